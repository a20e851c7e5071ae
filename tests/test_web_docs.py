"""docs/api.md is the API's OpenAPI schema rendered (fleet/web/apidoc.py), and up to date."""

from __future__ import annotations

from pathlib import Path

from fleet.web.api import openapi_schema
from fleet.web.apidoc import render

ROOT = Path(__file__).resolve().parent.parent


def test_the_api_reference_is_generated_from_the_current_schema():
    committed = (ROOT / "docs" / "api.md").read_text()
    assert committed == render(openapi_schema()), (
        "docs/api.md is out of date: python -m fleet.web.apidoc docs/api.md"
    )


def test_every_endpoint_and_object_is_in_the_reference():
    schema = openapi_schema()
    page = render(schema)
    for path, methods in schema["paths"].items():
        for method in methods:
            short = path.removeprefix("/api/v1")
            assert f"### `{method.upper()} {short}`" in page
    for name in schema["components"]["schemas"]:
        if name not in ("HTTPValidationError", "ValidationError"):
            assert f"### {name}\n" in page
    assert page.count("(**token**)") == sum(
        "security" in op for methods in schema["paths"].values() for op in methods.values()
    )
