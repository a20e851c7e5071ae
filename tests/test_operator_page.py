"""The operator's page in a real browser: headless Chromium (Debian's ``chromium`` and
``chromium-driver``, which .ci/run installs) driven by selenium, against a running controller
on 127.0.0.1.

The browser opens the page and sees the vehicles move (their drawn positions change), adds
an order through the form and sees it reach FINISHED, closes a segment on a vehicle's route
by clicking it and sees the route change, and forces a tag in the watch table; the page
logs no error. A screenshot is saved to ``build/screenshots/operator-page.png`` (the one in
docs/ is a copy of it). A second controller runs the warehouse with 100 vehicles: every one
is drawn and they move.

Every wait is a poll with a wall-clock deadline far beyond what the simulated time needs;
no duration is asserted. Where the browser cannot be started (not installed), the tests
skip and say why.
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from web_controller import ROOT, TOKEN, Controller

from blocks.dispatch.orders import TransportOrder
from topology import warehouse

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"
SCREENSHOTS = ROOT / "build" / "screenshots"
WAIT_WALL_S = 120.0
FLAGS = (  # headless as root in a sandbox with no network but loopback
    "--headless=new",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-dev-shm-usage",
    "--window-size=1280,900",
)

webdriver = pytest.importorskip("selenium.webdriver")
if not (Path(CHROMIUM).exists() and Path(CHROMEDRIVER).exists()):
    pytest.skip(
        f"no browser: {CHROMIUM} and {CHROMEDRIVER} are Debian's chromium and chromium-driver "
        "(.ci/run installs them)",
        allow_module_level=True,
    )

from selenium.common.exceptions import StaleElementReferenceException  # noqa: E402
from selenium.webdriver.chrome.service import Service  # noqa: E402
from selenium.webdriver.common.by import By  # noqa: E402
from selenium.webdriver.support.ui import Select, WebDriverWait  # noqa: E402


@pytest.fixture(scope="module")
def browser(tmp_path_factory) -> Iterator[webdriver.Chrome]:
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in FLAGS:
        options.add_argument(flag)
    options.add_argument(f"--user-data-dir={tmp_path_factory.mktemp('chromium')}")
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    try:
        yield driver
    finally:
        driver.quit()


@pytest.fixture(scope="module")
def page(browser):
    """The page of a running controller (the workshop with orders, 3 vehicles), live."""
    with Controller(speed=10) as ctl:
        browser.get(ctl.url + "/")
        wait(browser).until(lambda d: d.find_element(By.ID, "connection").text == "live")
        wait(browser).until(lambda d: d.find_elements(By.CSS_SELECTOR, "g.vehicle[data-x]"))
        browser.find_element(By.ID, "token").send_keys(TOKEN)
        yield browser, ctl


def wait(browser, wall_s: float = WAIT_WALL_S) -> WebDriverWait:
    return WebDriverWait(browser, wall_s, poll_frequency=0.1, ignored_exceptions=(
        StaleElementReferenceException,
    ))  # fmt: skip


def positions(browser) -> dict[str, tuple[float, float]]:
    """Each vehicle's drawn position (plant metres), as the page last drew it."""
    return {
        g.get_attribute("data-id"): (
            float(g.get_attribute("data-x")),
            float(g.get_attribute("data-y")),
        )
        for g in browser.find_elements(By.CSS_SELECTOR, "g.vehicle")
    }


def errors_logged(browser) -> list[dict]:
    """The browser console's errors (a refused request logs its own line: not an error of
    the page's)."""
    return [
        e
        for e in browser.get_log("browser")
        if e["level"] == "SEVERE" and "Failed to load resource" not in e["message"]
    ]


def test_the_page_draws_the_plant_and_every_vehicle(page):
    browser, ctl = page
    plant = ctl.program.cfg.plant
    segments = browser.find_elements(By.CSS_SELECTOR, "line.segment")
    pairs = {(min(a, b), max(a, b)) for a, b in plant.arc_index}
    drawn = {(int(s.get_attribute("data-a")), int(s.get_attribute("data-b"))) for s in segments}
    assert drawn == pairs
    assert sorted(int(i) for i in positions(browser)) == ctl.program.vehicles
    stations = browser.find_elements(By.CSS_SELECTOR, "text.queue-count")
    assert {int(t.get_attribute("data-station")) for t in stations} == set(
        plant.with_role("station")
    )
    assert not errors_logged(browser)


def test_the_vehicles_move_on_the_page(page):
    browser, _ = page
    first = positions(browser)
    wait(browser).until(lambda d: positions(d) != first)
    rows = browser.find_elements(By.CSS_SELECTOR, "#vehicles tbody tr")
    assert len(rows) == len(first)


def test_an_order_added_through_the_form_reaches_finished(page):
    browser, ctl = page
    order_id = f"page-{time.monotonic_ns()}"
    field = browser.find_element(By.ID, "order-id")
    field.clear()
    field.send_keys(order_id)
    Select(browser.find_element(By.ID, "order-get")).select_by_value("21")
    Select(browser.find_element(By.ID, "order-put")).select_by_value("24")
    browser.find_element(By.ID, "order-submit").click()
    wait(browser).until(lambda d: order_id in d.find_element(By.ID, "order-message").text)
    row = f'#orders tbody tr[data-id="{order_id}"] td.state'
    wait(browser).until(lambda d: d.find_element(By.CSS_SELECTOR, row).text == "FINISHED")
    assert ctl.call("GET", f"/api/v1/orders/{order_id}").body["state"] == "FINISHED"


def test_clicking_a_segment_closes_it_and_the_route_changes(page):
    """A segment three steps ahead on a vehicle's route, drawn on its route, clicked:
    closed in the controller, drawn closed, and the vehicle's route (the controller's and
    the drawn one) no longer crosses it; clicked again: open."""
    browser, ctl = page
    plant = ctl.program.cfg.plant

    def ahead(d):
        for v in ctl.call("GET", "/api/v1/vehicles").body:
            route = [*v["released"], *v["planned"]]
            for x, y in zip(route[2:], route[3:], strict=False):  # not about to be driven
                if (x, y) in plant.arc_index and (y, x) in plant.arc_index:
                    return v["id"], min(x, y), max(x, y)
        return None

    def drawn_ahead(d):
        """A segment ahead that the page draws on the vehicle's route right now."""
        found = ahead(d)
        if found is None:
            return None
        vehicle, a, b = found
        return found if crosses(drawn_route(d, vehicle), {centre(d, a), centre(d, b)}) else None

    vehicle, a, b = wait(browser).until(drawn_ahead)
    selector = f'line.segment[data-a="{a}"][data-b="{b}"]'
    browser.find_element(By.CSS_SELECTOR, selector).click()
    wait(browser).until(
        lambda d: "closed" in d.find_element(By.CSS_SELECTOR, selector).get_attribute("class")
    )
    try:
        assert [a, b] in ctl.call("GET", "/api/v1/blockades").body

        def avoids(d) -> bool:
            v = ctl.call("GET", f"/api/v1/vehicles/{vehicle}").body
            route = [v["node"], *v["released"], *v["planned"]]
            return {(a, b), (b, a)}.isdisjoint(zip(route, route[1:], strict=False))

        wait(browser).until(avoids)
        ends = {centre(browser, a), centre(browser, b)}
        wait(browser).until(lambda d: not crosses(drawn_route(d, vehicle), ends))
    finally:
        browser.find_element(By.CSS_SELECTOR, selector).click()
    wait(browser).until(
        lambda d: "closed" not in d.find_element(By.CSS_SELECTOR, selector).get_attribute("class")
    )
    assert ctl.call("GET", "/api/v1/blockades").body == []


def test_a_tag_is_forced_and_unforced_in_the_watch_table(page):
    browser, ctl = page
    row = watch(browser, "agv3.hold")
    browser.find_element(By.CSS_SELECTOR, f"{row} input.force-value").send_keys("1")
    browser.find_element(By.CSS_SELECTOR, f"{row} button.force").click()
    wait(browser).until(
        lambda d: d.find_element(By.CSS_SELECTOR, f"{row} td.forced").text == "forced"
    )
    assert ctl.program.rt.image.forces == {"agv3.hold": 1}
    wait(browser).until(lambda d: d.find_element(By.CSS_SELECTOR, f"{row} td.value").text == "1")
    wait(browser).until(
        lambda d: (
            "held" in d.find_element(By.CSS_SELECTOR, '#vehicles tr[data-id="3"] td.flags').text
        )
    )
    save_screenshot(browser)
    browser.find_element(By.CSS_SELECTOR, f"{row} button.unforce").click()
    wait(browser).until(lambda d: d.find_element(By.CSS_SELECTOR, f"{row} td.forced").text == "")
    assert ctl.program.rt.image.forces == {}
    ctl.call("PUT", "/api/v1/tags/agv3.hold", {"value": 0}, token=TOKEN)
    assert not errors_logged(browser)


def test_a_read_only_tag_cannot_be_forced_from_the_page(page):
    browser, _ = page
    row = watch(browser, "agv1.node")
    for kind in ("write", "force", "unforce"):
        assert not browser.find_element(By.CSS_SELECTOR, f"{row} button.{kind}").is_enabled()


def watch(browser, name: str) -> str:
    """Add a tag to the watch table; the CSS selector of its row, once it is shown."""
    browser.find_element(By.ID, "watch-name").send_keys(name)
    browser.find_element(By.ID, "watch-add").click()
    row = f'#watch tbody tr[data-name="{name}"]'
    wait(browser).until(lambda d: d.find_elements(By.CSS_SELECTOR, row))
    return row


def centre(browser, node: int) -> tuple[float, float]:
    """Where the page draws a node, in the map's coordinates (rounded to 0.01)."""
    box = browser.execute_script(
        "const b = document.querySelector(`#plant [data-node='${arguments[0]}']`).getBBox();"
        "return [b.x + b.width / 2, b.y + b.height / 2];",
        node,
    )
    return round(box[0], 2), round(box[1], 2)


def drawn_route(browser, vehicle: int) -> list[tuple[float, float]]:
    """The vehicle's released and planned route as drawn, point by point."""
    points: list[tuple[float, float]] = []
    for kind in ("released", "planned"):
        line = browser.find_element(
            By.CSS_SELECTOR, f'polyline.route.{kind}[data-vehicle="{vehicle}"]'
        )
        for p in (line.get_attribute("points") or "").split():
            x, y = map(float, p.split(","))
            points.append((round(x, 2), round(y, 2)))
    return points


def crosses(points: list[tuple[float, float]], ends: set[tuple[float, float]]) -> bool:
    """Whether two consecutive points of a drawn route are a segment's two ends."""
    return any({p, q} == ends for p, q in zip(points, points[1:], strict=False))


def save_screenshot(browser) -> Path:
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    path = SCREENSHOTS / "operator-page.png"
    browser.execute_script("window.scrollTo(0, 0)")
    browser.save_screenshot(str(path))
    return path


def test_a_hundred_vehicles_are_drawn_and_move(browser, tmp_path):
    """The warehouse plant with 100 vehicles (no orders): every vehicle drawn, and they move."""
    config = tmp_path / "warehouse-100.toml"
    config.write_text(warehouse_with(100))
    with Controller(speed=5, config=config) as ctl:
        browser.get(ctl.url + "/")
        wait(browser).until(lambda d: d.find_element(By.ID, "connection").text == "live")
        wait(browser).until(
            lambda d: len(d.find_elements(By.CSS_SELECTOR, "g.vehicle[data-x]")) == 100
        )
        first = positions(browser)
        wait(browser).until(lambda d: sum(p != first[k] for k, p in positions(d).items()) >= 10)
        assert len(browser.find_elements(By.CSS_SELECTOR, "#vehicles tbody tr")) == 100
        assert not errors_logged(browser)
    shutil.rmtree(tmp_path, ignore_errors=True)


def warehouse_with(n: int) -> str:
    """examples/warehouse.toml with ``n`` vehicles: along the top and bottom border rows
    first (cells 46 apart per row), then on the other aisle cells in id order."""
    text = (ROOT / "examples" / "warehouse.toml").read_text()
    head = text[: text.index("[[vehicles]]")]
    plant = warehouse()
    free = [i for i in sorted(plant.index) if plant.node(i).role == "transit"]
    border = [i for i in free if i < 46 or i >= 32 * 46]
    starts = (border + [i for i in free if i not in border])[:n]
    return head + "".join(
        f"[[vehicles]]\nid = {v}\nstart = {s}\n\n" for v, s in enumerate(starts, start=1)
    )


def test_the_vehicle_table_says_who_tops_up_and_who_must_charge(browser, tmp_path):
    """The distribution centre with three vehicles at 50 % and no order due: they top up on
    three of its five chargers, and the table's job column says so, as the API's phase."""
    text = (ROOT / "examples" / "distribution-centre.toml").read_text()
    plant = ROOT / "examples" / "plants" / "distribution-centre.toml"
    head = text[: text.index("[orders]")].replace('"plants/distribution-centre.toml"', f'"{plant}"')
    rest = text[text.index("[dispatch]") : text.index("[[vehicles]]")]
    starts = "".join(
        f"[[vehicles]]\nid = {v}\nstart = {300 + v}\nbattery = 50\n\n" for v in (1, 2, 3)
    )
    orders = tmp_path / "late.csv"  # the only order, due long after the test
    orders.write_text("id,get,put,start_s\nlate,31,41,100000\n")
    config = tmp_path / "topping-up.toml"
    config.write_text(f'{head}[orders]\nfile = "{orders}"\n\n{rest}{starts}')
    # (at 5 x real time the vehicles drive to their chargers for some 18 s: the page sees it)
    with Controller(speed=5, config=config) as ctl:
        browser.get(ctl.url + "/")
        wait(browser).until(lambda d: d.find_element(By.ID, "connection").text == "live")

        def jobs(d) -> list[str]:
            return [td.text for td in d.find_elements(By.CSS_SELECTOR, "#vehicles td.order")]

        wait(browser).until(lambda d: "to charger (topping up)" in jobs(d))
        wait(browser).until(lambda d: jobs(d) == ["topping up"] * 3)
        phases = {v["id"]: v["phase"] for v in ctl.call("GET", "/api/v1/vehicles").body}
        assert phases == {1: "topping_up", 2: "topping_up", 3: "topping_up"}
        assert not errors_logged(browser)
    shutil.rmtree(tmp_path, ignore_errors=True)


def test_the_order_list_shows_the_newest_orders_when_old_ones_have_left_the_book(browser, tmp_path):
    """1,200 orders added; the first 600 and the newest 400 withdrawn and swept from the
    book (kept 1 s). The page reads the newest orders by position, not the first ones the
    book still holds, and reads further back where the newest positions are gaps: its 200
    rows are s799 down to s600."""
    text = (ROOT / "examples" / "workshop-orders.toml").read_text()
    text = text.replace("[orders]\n", "[orders]\nkeep_final_s = 1\n")
    text = text.replace(
        '"orders/workshop.csv"', f'"{ROOT / "examples" / "orders" / "workshop.csv"}"'
    )
    text = text.replace(
        '"plants/workshop.toml"', f'"{ROOT / "examples" / "plants" / "workshop.toml"}"'
    )
    config = tmp_path / "swept.toml"
    config.write_text(text)
    with Controller(speed=10, config=config) as ctl:
        orders = ctl.program.orders
        for k in range(1200):  # never startable in this test: none ends by itself
            orders.submit(TransportOrder(f"s{k}", 20, 21, start_s=1e6))
        gone = [*range(600), *range(800, 1200)]
        for k in gone:
            orders.withdraw(f"s{k}")
        book = orders.book
        deadline = time.monotonic() + 60
        while any(f"s{k}" in book for k in gone) and time.monotonic() < deadline:
            time.sleep(0.1)  # the scan sweeps them a simulated second after they end
        assert not any(f"s{k}" in book for k in gone)
        browser.get(ctl.url + "/")
        wait(browser).until(lambda d: d.find_element(By.ID, "connection").text == "live")

        def ids(d) -> list[str]:
            return [td.text for td in d.find_elements(By.CSS_SELECTOR, "#orders tbody td.id")]

        # (the workshop's own orders come first while they are in the book)
        wait(browser).until(lambda d: ids(d) == [f"s{k}" for k in range(799, 599, -1)])
        assert not errors_logged(browser)
    shutil.rmtree(tmp_path, ignore_errors=True)
