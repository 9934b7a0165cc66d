#!/usr/bin/python3
"""The operator's console in a real browser (issue #20): headless Chromium, driven by
ChromeDriver through Selenium (Debian's chromium, chromium-driver and python3-selenium), against
goniod on the simulated instrument. Run by console_test.sh, which starts both.

What it checks, as an operator would see it:
  - the page loads from goniod's address, read-only without the token; a change asked from the
    page without the token is refused (401, said on the page) and so is one from a plain HTTP
    client; the token typed once is never shown on the page nor put in a URL;
  - the camera view: a snap between runs shows a frame (not blank); a rectangle dragged on it is
    described in mm with its spread of directions, and put into the plan's text; the run then
    measures through it (its frames show it);
  - the instrument's plans (goniod --plans) are offered, and one chosen fills the plan's text; a
    schedule whose plan is one of them is dry-run from the page (each entry, its points, its
    time), queuing nothing;
  - a plan's dry run shows its points and time, and queues nothing; submitted, its points appear
    in the lobe plot as they are stored, with the temperature, exposure and monitor plots beside;
  - pause stops the run after its point (no new points while paused), resume continues it, and
    the run finishes with every point drawn; abort asks first, "keep running" keeps it running;
  - the fit asked from the page says what it is doing while it runs (goniod's fit_progress
    events), then lists its fits and draws the one BIC prefers;
  - a past run opens with its events, and its CSV link gives the run's CSV.
It saves screenshots (the README's comes from scripts/console_screenshot.py) and prints what the
page measured of itself: time to first paint and, per new point, ms from the point's event to the
point drawn.

Usage: console_test.py URL TOKEN PLAN OUTDIR SCHEDULE
"""
import json
import os
import statistics
import sys
import time
import urllib.error
import urllib.request

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "scripts"))
from headless_chromium import headless_chromium  # noqa: E402
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.by import By

url, token, plan, outdir, schedule = sys.argv[1:6]
failures = []


def check(cond, what):
    if not cond:
        failures.append(what)
        print("FAIL:", what, flush=True)
    return cond


def fatal(what):
    print("FAIL:", what, flush=True)
    try:
        driver.save_screenshot(f"{outdir}/console_failure.png")
        print("page message:", driver.find_element(By.ID, "message").text)
        print("state:", driver.find_element(By.ID, "state").text)
    except Exception as e:  # the browser may be what failed
        print("(no screenshot:", e, ")")
    sys.exit(1)


def wait_for(pred, what, timeout=60.0):
    end = time.monotonic() + timeout
    last = None
    while time.monotonic() < end:
        try:
            last = pred()
            if last:
                return last
        except Exception as e:  # an element being redrawn
            last = e
        time.sleep(0.1)
    fatal(f"{what} (after {timeout:.0f} s; last: {last!r})")


def text(id_):
    return driver.find_element(By.ID, id_).text


def state():
    return driver.find_element(By.ID, "state").get_attribute("data-state")


def points():
    return len(driver.find_elements(By.CSS_SELECTOR, "#lobe circle.point"))


def http(method, path, body=None, auth=False):
    req = urllib.request.Request(url + path, method=method,
                                 data=None if body is None else json.dumps(body).encode())
    if auth:
        req.add_header("Authorization", "Bearer " + token)
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, r.read().decode("utf-8", "replace"), r.headers
    except urllib.error.HTTPError as e:
        return e.code, e.read().decode("utf-8", "replace"), e.headers


# What goniod serves, seen by a plain HTTP client.
code, body, headers = http("GET", "/console/")
check(code == 200 and "<title>gonio console</title>" in body, f"GET /console/: {code}")
check("default-src 'self'" in (headers.get("Content-Security-Policy") or ""),
      "the page is served with a Content-Security-Policy that allows only its own origin")
code, body, _ = http("GET", "/console/nothing.js")
check(code == 404 and "no file" in body, f"an unknown console file is a 404 (got {code})")
code, body, _ = http("POST", "/api/v1/pause", {})
check(code == 401, f"a mutation without the token from a plain client is refused (got {code})")

driver = headless_chromium(1500, 1100)
try:
    driver.get(url + "/")
    check(driver.current_url.endswith("/console/"), f"/ leads to the console ({driver.current_url})")
    wait_for(lambda: state() == "idle", "the page shows goniod idle")
    check(text("token-state") == "read-only", "without a token the page says it is read-only")
    paint = driver.execute_script(
        "return performance.getEntriesByType('paint').map(e => [e.name, e.startTime]);")

    # Without the token: the page's submit is refused with 401, and it says so.
    driver.find_element(By.ID, "plan-file").send_keys(plan)
    driver.find_element(By.ID, "submit").click()
    msg = wait_for(lambda: "401" in text("message") and text("message"),
                   "the page shows the refusal of a submit without the token")
    check("token" in msg, f"the refusal says what is missing: {msg!r}")
    check(not driver.find_elements(By.CSS_SELECTOR, "#jobs tr[data-state='queued']"),
          "nothing was queued without the token")

    # The token, typed once: never on the page, never in the URL.
    driver.find_element(By.ID, "token").send_keys(token)
    driver.find_element(By.ID, "token-set").click()
    wait_for(lambda: "changes allowed" in text("token-state"), "the token is taken")
    check(token not in driver.page_source and token not in driver.current_url,
          "the token is nowhere on the page or in its URL")

    # The instrument's plans: the catalogue's plan fills the text box.
    from selenium.webdriver.support.ui import Select
    catalogue = Select(driver.find_element(By.ID, "plan-catalogue"))
    names = [o.text for o in catalogue.options]
    check(any(n.startswith("console_plan.toml - The console test's plan") for n in names),
          f"the instrument's plans are offered with their descriptions ({names})")
    driver.find_element(By.ID, "plan-text").clear()
    catalogue.select_by_value("console_plan.toml")
    wait_for(lambda: driver.find_element(By.ID, "plan-text").get_attribute("value")
             .startswith("# The console test's plan"), "a catalogue plan fills the plan's text")

    # A schedule naming that plan, dry-run from the page: its entry, its points, nothing queued.
    driver.find_element(By.ID, "schedule-file").send_keys(schedule)
    driver.find_element(By.ID, "schedule-dry-run").click()
    sched = wait_for(lambda: "in all" in text("schedule-result") and text("schedule-result"),
                     "the schedule's dry run shows its entries")
    print("schedule dry run:", sched.replace("\n", " | "))
    check("console_plan.toml (line 1) × 2: 14 points" in sched and "fits beckmann" in sched,
          f"the dry run names the entry, its repeats, points and fit: {sched!r}")
    check(not driver.find_elements(By.CSS_SELECTOR, "#jobs tr[data-state='queued']"),
          "a schedule's dry run queues nothing")

    # The camera view: a snap between runs, then a rectangle dragged about the sample's centre.
    check('sample = "ground-glass-G1"' in driver.find_element(By.ID, "plan-text")
          .get_attribute("value"), "the chosen plan is shown in the plan's text box")
    driver.find_element(By.ID, "snap-exposure").clear()
    driver.find_element(By.ID, "snap-exposure").send_keys("0.1")
    driver.find_element(By.ID, "snap").click()
    wait_for(lambda: text("frame-info").startswith("snap"), "a snap shows its frame")
    frame = driver.find_element(By.ID, "frame")
    lit = driver.execute_script("""
        const c = document.getElementById('frame');
        const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
        let lit = 0, levels = new Set();
        for (let i = 0; i < d.length; i += 4) { if (d[i] > 0) ++lit; levels.add(d[i]); }
        return [c.width, c.height, lit, levels.size];""")
    check(lit[0] == 512 and lit[1] == 512, f"the frame is shown at the camera's size ({lit[:2]})")
    check(lit[2] > 1000 and lit[3] > 20, f"the frame is not blank ({lit[2]} lit, {lit[3]} levels)")
    # Page offsets of frame pixels (247, 238) and (259, 262), from the element's centre.
    box = driver.execute_script(
        "const b = document.getElementById('frame').getBoundingClientRect();"
        "return [b.width, b.height];")
    def offset(px, py):
        return (round((px + 0.5) / 512 * box[0] - box[0] / 2),
                round((py + 0.5) / 512 * box[1] - box[1] / 2))
    (ax, ay), (bx, by) = offset(247, 238), offset(259, 262)
    ActionChains(driver).move_to_element_with_offset(frame, ax, ay).click_and_hold() \
        .move_by_offset((bx - ax) // 2, (by - ay) // 2).move_by_offset(bx - ax - (bx - ax) // 2,
                                                                     by - ay - (by - ay) // 2) \
        .release().perform()
    info = wait_for(lambda: "mm at the sample" in text("rect-info") and text("rect-info"),
                    "the dragged rectangle is described in mm with its spread of directions")
    print("rectangle:", info)
    check("view directions spread" in info, f"the spread of view directions is shown: {info!r}")
    toml = driver.find_element(By.ID, "rect-toml").text
    dragged = dict(line.split(" = ") for line in toml.splitlines()[1:])
    dragged = {k: int(v) for k, v in dragged.items()}
    check(abs(dragged["x"] - 247) <= 2 and abs(dragged["width"] - 13) <= 3 and
          abs(dragged["height"] - 25) <= 3, f"the rectangle is where it was dragged ({dragged})")
    driver.find_element(By.ID, "rect-to-plan").click()
    plan_text = driver.find_element(By.ID, "plan-text").get_attribute("value")
    check(f"\nx = {dragged['x']}\n" in plan_text and
          f"height = {dragged['height']}" in plan_text and "x = 253" not in plan_text,
          f"the plan's [rectangle] is the dragged one:\n{plan_text}")
    driver.save_screenshot(f"{outdir}/console_rectangle.png")

    # Dry run: what the plan would do, nothing queued.
    driver.find_element(By.ID, "dry-run").click()
    dry = wait_for(lambda: "points" in text("dry-run-result") and text("dry-run-result"),
                   "the dry run shows the plan's points and time")
    print("dry run:", dry)
    check(not driver.find_elements(By.CSS_SELECTOR, "#jobs tr[data-state='queued']"),
          "a dry run queues nothing")

    # Submit, and watch points arrive.
    driver.find_element(By.ID, "submit").click()
    wait_for(lambda: "queued as job" in text("message"), "the page says the plan was queued")
    wait_for(lambda: state() == "running", "the run starts")
    wait_for(lambda: points() >= 2, "points appear in the lobe plot", timeout=90)
    driver.save_screenshot(f"{outdir}/console_running.png")
    check(len(driver.find_elements(By.CSS_SELECTOR, "#temperature polyline")) == 1 and
          len(driver.find_elements(By.CSS_SELECTOR, "#exposure polyline")) == 1 and
          len(driver.find_elements(By.CSS_SELECTOR, "#monitor polyline")) == 1,
          "the temperature, exposure and monitor plots are drawn")
    # The run's frames replace the snap, with the run's rectangle: the one dragged.
    wait_for(lambda: text("frame-info").startswith("run "), "the run's frames show in the view")
    code, body, _ = http("GET", "/api/v1/frame")
    check(code == 200 and json.loads(body)["rectangle"] == dragged,
          f"the run measures through the dragged rectangle ({body[:300]})")
    check("Run " in text("run-title"), f"the run is named: {text('run-title')!r}")

    # Pause: no new point while paused; resume.
    driver.find_element(By.ID, "pause").click()
    wait_for(lambda: state() == "paused", "pause from the page pauses the run", timeout=60)
    # The page fetches the status and the run's points separately: on a loaded host it can show
    # "paused" before it has fetched the run's last point (a local ctest beside two coverage
    # runs). The count is the stored one; the page must catch up to it, then hold.
    def stored():
        code, body, _ = http("GET", "/api/v1/runs/1")
        return len(json.loads(body)["measurements"]) if code == 200 else -1
    n = stored()
    wait_for(lambda: points() == n, f"the page shows the {n} points stored when paused", timeout=30)
    time.sleep(2.5)  # more than two of the page's fetch periods
    check(points() == n and stored() == n,
          f"no new point while paused ({n} then {points()} shown, {stored()} stored)")
    check(not driver.find_element(By.ID, "resume").get_attribute("disabled"),
          "resume is offered while paused")
    driver.find_element(By.ID, "resume").click()
    wait_for(lambda: state() == "running" or points() > n, "resume continues the run")

    # Abort asks first; "keep running" keeps it running.
    driver.find_element(By.ID, "abort").click()
    check(driver.find_element(By.ID, "abort-confirm").is_displayed(), "abort asks for confirmation")
    check("Abort run" in text("abort-question"), f"it names the run: {text('abort-question')!r}")
    driver.find_element(By.ID, "abort-no").click()
    check(not driver.find_element(By.ID, "abort-confirm").is_displayed(),
          "keep running closes the question")

    # The run finishes with every point drawn.
    wait_for(lambda: "done" in text("run-summary"), "the run finishes", timeout=180)
    summary = text("run-summary")
    done, total = summary.split(", ")[1].split(" points")[0].split(" of ")
    wait_for(lambda: points() == int(total), f"every point of the run is drawn ({summary})")
    check(int(done) == int(total), f"the run measured every point: {summary}")
    kinds = [e.get_attribute("data-kind")
             for e in driver.find_elements(By.CSS_SELECTOR, "#events tbody tr")]
    check("paused" in kinds, f"the events show the pause ({kinds})")
    incidences = {g.get_attribute("data-incidence")
                  for g in driver.find_elements(By.CSS_SELECTOR, "#lobe g[data-incidence]")}
    check(incidences == {"0", "30"}, f"one series per incidence ({incidences})")
    # Fit the run from the page: both fits listed, the one BIC prefers drawn through the points.
    # Every text the message line takes is recorded: the fit's progress events (fit_progress)
    # pass through it for as long as the fit runs, then the fit's own result replaces them.
    driver.execute_script("""
      window.messagesSeen = [];
      new MutationObserver(() => window.messagesSeen.push(
          document.getElementById('message').textContent))
        .observe(document.getElementById('message'),
                 {childList: true, characterData: true, subtree: true});""")
    driver.find_element(By.ID, "fit").click()
    wait_for(lambda: len(driver.find_elements(By.CSS_SELECTOR, "#fits tr[data-fit]")) == 2,
             "the page's fit stores Beckmann and GGX and lists them",
             # The fit with the instrument response and the geometry's refits: seconds natively,
             # minutes under the sanitizers (CI: more than 120 s).
             timeout=400)
    wait_for(lambda: len(driver.find_elements(By.CSS_SELECTOR, "#lobe polyline.fit")) == 2,
             "the fit is drawn on the lobe, one dashed line per incidence")
    seen = driver.execute_script("return window.messagesSeen;") or []
    check(any(m.startswith("fitting run 1, ") for m in seen),
          f"the fit's progress was shown while it ran (the message line took {seen[:6]!r})")
    shown_fit = driver.find_element(By.CSS_SELECTOR, "#fits tr.selected").get_attribute("data-fit")
    code, body, _ = http("GET", f"/api/v1/runs/1/fits/{shown_fit}/prediction")
    pred = json.loads(body)["points"] if code == 200 else []
    check(len(pred) == int(total), f"the fit's prediction has every point ({code}, {len(pred)})")
    code, body, _ = http("GET", "/api/v1/runs/1")
    measured = {m["index"]: m["value"] for m in json.loads(body)["measurements"]}
    ratios = sorted(p["value"] / measured[p["index"]] for p in pred if measured[p["index"]] > 0)
    check(ratios and 0.8 < ratios[len(ratios) // 2] < 1.25,
          f"the drawn fit goes through the points (median model/value {ratios[len(ratios) // 2]:.3f})"
          if ratios else "no ratios")
    # The other fit can be drawn instead.
    other = driver.find_element(By.CSS_SELECTOR, "#fits tr[data-fit]:not(.selected) button")
    other.click()
    wait_for(lambda: driver.find_element(By.CSS_SELECTOR, "#fits tr.selected")
             .get_attribute("data-fit") != shown_fit, "'draw' draws the other fit")
    driver.save_screenshot(f"{outdir}/console_done.png")

    # A second run, aborted from the page after the question.
    driver.find_element(By.ID, "submit").click()
    wait_for(lambda: state() == "running" and "Run 2" in text("run-title"), "a second run starts")
    driver.find_element(By.ID, "abort").click()
    driver.find_element(By.ID, "abort-yes").click()
    wait_for(lambda: "aborted" in text("run-summary"), "abort from the page ends the run", 90)

    # A past run: open run 1 (the follow box goes off), its CSV link gives its CSV.
    run1 = "#runs tr[data-run='1']"
    driver.find_element(By.CSS_SELECTOR, run1 + " button").click()
    wait_for(lambda: text("run-title").startswith("Run 1"), "a past run opens")
    check(not driver.find_element(By.ID, "follow").is_selected(), "opening a run stops following")
    check("selected" in driver.find_element(By.CSS_SELECTOR, run1).get_attribute("class"),
          "the opened run is marked in the list")
    href = driver.find_element(By.CSS_SELECTOR, run1 + " a").get_attribute("href")
    code, csv, _ = http("GET", href[len(url):])
    check(code == 200 and csv.count("\n") >= int(total), f"the CSV link gives the run ({code})")

    shown = driver.execute_script("return window.gonioMetrics.pointShownMs;")
    fetches = driver.execute_script("return window.gonioMetrics.fetches;")
    fp = dict(paint).get("first-contentful-paint")
    print(f"first contentful paint: {fp:.0f} ms" if fp is not None else "no paint timing")
    if shown:
        print(f"new point shown after its event: median {statistics.median(shown):.0f} ms, "
              f"max {max(shown):.0f} ms over {len(shown)} points; {fetches} API requests")
    check(len(shown) >= 3, f"the page measured its latency on several points ({len(shown)})")
finally:
    driver.quit()

if failures:
    print(f"{len(failures)} check(s) failed")
    sys.exit(1)
print("console: every check passed")
