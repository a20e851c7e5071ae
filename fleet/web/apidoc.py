"""docs/api.md from the API's OpenAPI schema: ``python -m fleet.web.apidoc [FILE]``.

The reference is generated, never written by hand, so it cannot drift from what the server
answers: the schema comes from the same pydantic models and routes the server uses, and a
test regenerates the page and compares it with the committed one. Without FILE the page is
printed.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from .api import PREFIX, openapi_schema

HEADER = """# HTTP API reference

Generated from the OpenAPI schema the server serves at `/openapi.json` (version {version});
do not edit by hand: `python -m fleet.web.apidoc docs/api.md` writes it again, and
`tests/test_web_docs.py` fails when it is out of date. How to start the server, the
operator's page and the security rules: [operator-guide.md](operator-guide.md),
[security.md](security.md#the-http-api). Every path below is under `{prefix}`.

Every error is a JSON object `{{"error": "one line", "field": "name" or null}}`; the status
codes each endpoint may answer are listed with it; a method a path does not take is 405,
for every path. Methods marked **token** need the header `Authorization: Bearer TOKEN`:
401 without it, 403 with a wrong one. The token is checked before anything else of a
request that may change something (POST, PUT, DELETE, PATCH), so such a request on a path
that does not take it is 405 only with the right token, 401 or 403 without it.
"""


def render(schema: dict[str, Any]) -> str:
    parts = [HEADER.format(version=schema["info"]["version"], prefix=PREFIX)]
    parts.append("## Endpoints\n")
    for path, methods in schema["paths"].items():
        for method, op in methods.items():
            parts.append(_operation(path, method, op))
    parts.append("## Objects\n")
    for name, model in schema["components"]["schemas"].items():
        if name in ("HTTPValidationError", "ValidationError"):
            continue
        parts.append(_model(name, model))
    return "\n".join(parts).rstrip() + "\n"


def _operation(path: str, method: str, op: dict[str, Any]) -> str:
    short = path.removeprefix(PREFIX) or "/"
    token = " (**token**)" if "security" in op else ""
    lines = [f"### `{method.upper()} {short}`{token}\n", _cell(op.get("description", "")), ""]
    params = op.get("parameters", [])
    if params:
        lines += ["| parameter | in | type | required | meaning |", "|---|---|---|---|---|"]
        for p in params:
            s = p.get("schema", {})
            lines.append(
                f"| `{p['name']}` | {p['in']} | {_type(s)}{_bounds(s)} | "
                f"{'yes' if p.get('required') else 'no'} | {_cell(p.get('description', ''))} |"
            )
        lines.append("")
    body = op.get("requestBody")
    if body:
        ref = body["content"]["application/json"]["schema"]
        lines += [f"Body: {_type(ref)}.", ""]
    ok = [code for code in op["responses"] if code.startswith("2")]
    answer = op["responses"][ok[0]]
    content = answer.get("content", {})
    if "application/json" in content:
        result = _type(content["application/json"]["schema"])
    else:
        result = ", ".join(f"`{kind}`" for kind in content) or "-"
    errors = sorted(code for code in op["responses"] if not code.startswith("2"))
    lines += [f"Answer: {ok[0]}, {result}. Errors: {', '.join(errors) or 'none'}.", ""]
    return "\n".join(lines)


def _model(name: str, model: dict[str, Any]) -> str:
    lines = [f"### {name}\n"]
    if model.get("description"):
        lines += [" ".join(model["description"].split()), ""]
    required = set(model.get("required", ()))
    lines += ["| field | type | required | meaning |", "|---|---|---|---|"]
    for field, s in model.get("properties", {}).items():
        default = f" (default {s['default']!r})" if "default" in s else ""
        lines.append(
            f"| `{field}` | {_type(s)}{_bounds(s)} | {'yes' if field in required else 'no'} | "
            f"{_cell(s.get('description', ''))}{default} |"
        )
    return "\n".join(lines) + "\n"


def _type(s: dict[str, Any]) -> str:
    """A schema as a short type: integer, string or null, list of NodeOut, ..."""
    if "$ref" in s:
        name = s["$ref"].rsplit("/", 1)[1]
        return f"[{name}](#{name.lower()})"
    if "anyOf" in s:
        return " or ".join(_type(x) for x in s["anyOf"])
    kind = s.get("type")
    if kind == "array":
        return f"list of {_type(s.get('items', {}))}"
    if kind == "object":
        extra = s.get("additionalProperties")
        return f"object of {_type(extra)}" if isinstance(extra, dict) and extra else "object"
    return kind or "any"


def _bounds(s: dict[str, Any]) -> str:
    marks = {
        "minimum": ">=",
        "maximum": "<=",
        "exclusiveMinimum": ">",
        "minLength": "length >=",
        "maxLength": "length <=",
    }
    found = [f"{mark} {s[key]}" for key, mark in marks.items() if key in s]
    return f" ({', '.join(found)})" if found else ""


def _cell(text: str) -> str:
    return " ".join(text.split()).replace("|", "\\|")


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    page = render(openapi_schema())
    if args:
        Path(args[0]).write_text(page)
    else:
        sys.stdout.write(page)
    return 0


if __name__ == "__main__":
    sys.exit(main())
