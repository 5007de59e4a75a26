"""The console page as a person uses it: what they see and what they press.

Everything is read from the DOM (text, attributes, the markers' `data-*`
positions), never from the page's JavaScript objects.
"""

from __future__ import annotations

import math
import time

from selenium.common.exceptions import StaleElementReferenceException
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.by import By
from selenium.webdriver.common.keys import Keys
from selenium.webdriver.support.ui import WebDriverWait

from harness import SCREENSHOTS, WAIT


class Page:
    def __init__(self, driver):
        self.driver = driver

    # Loading -------------------------------------------------------------

    def open(self, daemon) -> None:
        """Loads the console from `daemon` itself."""
        self.driver.get(daemon.http_url)
        self.wait(lambda: self.text("conn").startswith("connected"), "the page connects")

    def resize(self, width: int, height: int) -> None:
        self.driver.set_window_size(width, height)

    # Reading -------------------------------------------------------------

    def el(self, element_id: str):
        return self.driver.find_element(By.ID, element_id)

    def text(self, element_id: str) -> str:
        return self.el(element_id).text

    def shown(self, element_id: str) -> bool:
        return self.el(element_id).is_displayed()

    def marker(self, element_id: str) -> dict:
        """A plot marker's world (`n`, `e`) and screen (`x`, `y`) position."""
        node = self.el(element_id)
        values = {k: node.get_attribute(f"data-{k}") for k in ("n", "e", "x", "y")}
        if None in values.values():
            return {}
        return {k: float(v) for k, v in values.items()}

    def view(self) -> dict:
        """The plot's centre (metres), scale (px per metre) and size (px)."""
        svg = self.el("plot")
        return {
            "n": float(svg.get_attribute("data-center-n")),
            "e": float(svg.get_attribute("data-center-e")),
            "scale": float(svg.get_attribute("data-scale")),
            "width": svg.size["width"],
            "height": svg.size["height"],
        }

    def log_entries(self) -> list[dict]:
        """The log, newest first: request, `data-ret` and message of each exchange."""
        out = []
        for item in self.driver.find_elements(By.CSS_SELECTOR, "#log > li.entry:not(.note)"):
            try:
                out.append({
                    "request": item.find_element(By.CSS_SELECTOR, ".request").text,
                    "ret": item.get_attribute("data-ret"),
                    "status": item.find_element(By.CSS_SELECTOR, ".ret").text,
                    "text": item.text,
                })
            except StaleElementReferenceException:
                continue
        return out

    def event_lines(self) -> list[dict]:
        """The event log, oldest first: `kind` (`event` or `marker`), `name`,
        `text` and `seq` (None for a marker without one) of each line."""
        out = []
        for item in self.driver.find_elements(By.CSS_SELECTOR, "#events > li"):
            try:
                seq = item.get_attribute("data-seq")
                out.append({
                    "kind": "marker" if "marker" in item.get_attribute("class").split() else "event",
                    "name": item.get_attribute("data-name"),
                    "text": item.find_element(By.CSS_SELECTOR, ".text").text,
                    "seq": None if seq is None else int(seq),
                })
            except StaleElementReferenceException:
                continue
        return out[::-1]

    def wait(self, condition, what: str, timeout: float = WAIT):
        """Waits until `condition()` is truthy; fails saying `what` did not happen."""
        last = None

        def check(_):
            nonlocal last
            try:
                last = condition()
            except (StaleElementReferenceException, KeyError, ValueError, TypeError) as e:
                # Not there yet: a marker not drawn, a number not shown.
                last = e
                return False
            return last

        try:
            return WebDriverWait(self.driver, timeout, poll_frequency=0.1).until(check)
        except Exception as e:  # a TimeoutException, said in words
            raise AssertionError(f"timed out waiting until {what} (last: {last!r})\n{self.describe()}") from e

    def describe(self) -> str:
        """What the page shows, for a failure message."""
        try:
            parts = [f"{i}: {self.text(i)!r}" for i in ("conn", "role", "age", "fsm", "armed", "last-result")]
            parts += [f"log: {e['text']!r}" for e in self.log_entries()[:4]]
            parts += [f"events-conn: {self.text('events-conn')!r}"]
            parts += [f"event: {e['name']} {e['text']!r} seq {e['seq']}" for e in self.event_lines()[-12:]]
            return "\n".join(parts)
        except Exception as e:  # the page itself may be gone
            return f"(page unreadable: {e})"

    # Doing ---------------------------------------------------------------

    def click(self, element_id: str) -> None:
        self.el(element_id).click()

    def login(self, password: str) -> None:
        self.wait(lambda: self.shown("login"), "the login form shows")
        field = self.el("password")
        field.clear()
        field.send_keys(password, Keys.ENTER)

    def confirm(self, expect_command_prefix: str = "") -> str:
        """Presses OK in the confirmation dialog; returns the command it showed."""
        self.wait(lambda: self.shown("confirm"), "the confirmation dialog opens")
        command = self.text("confirm-command")
        assert command.startswith(expect_command_prefix), command
        self.click("confirm-ok")
        self.wait(lambda: not self.shown("confirm"), "the dialog closes")
        return command

    def command(self, line: str) -> None:
        """Types a line into the command line and sends it with Enter."""
        field = self.el("command")
        field.clear()
        field.send_keys(line, Keys.ENTER)

    def click_plot_at(self, north: float, east: float) -> None:
        """Clicks the plot where the world point (north, east) is drawn."""
        v = self.view()
        dx = (east - v["e"]) * v["scale"]
        dy = -(north - v["n"]) * v["scale"]
        assert abs(dx) < v["width"] / 2 and abs(dy) < v["height"] / 2, f"({north}, {east}) is outside the view {v}"
        ActionChains(self.driver).move_to_element_with_offset(self.el("plot"), round(dx), round(dy)).click().perform()

    def screenshot(self, name: str) -> str:
        """Saves the window as target/console-screenshots/NAME.png."""
        path = SCREENSHOTS / f"{name}.png"
        time.sleep(0.3)  # let the last poll's answer be drawn
        self.driver.save_screenshot(str(path))
        return str(path)


def distance(a: dict, b: dict, keys=("n", "e")) -> float:
    return math.hypot(*(a[k] - b[k] for k in keys))
