#!/usr/bin/python3
"""A screenshot of the operator's console (the README's): headless Chromium on a running goniod,
read-only (no token). Waits until the shown run has MIN_POINTS points and the camera view a frame,
drags a rectangle about the frame's centre (its coverage is a read), then saves the page.

Usage: scripts/console_screenshot.py URL OUT.png [MIN_POINTS]
  e.g. during ./scripts/demo.sh, with the address it prints:
  scripts/console_screenshot.py http://127.0.0.1:PORT/console/ docs/figures/console_demo.png 30
"""
import sys
import time

from headless_chromium import headless_chromium
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.by import By

url, out = sys.argv[1:3]
min_points = int(sys.argv[3]) if len(sys.argv) > 3 else 20

driver = headless_chromium(1500, 1000)
try:
    driver.get(url)
    end = time.monotonic() + 900
    while time.monotonic() < end:
        points = len(driver.find_elements(By.CSS_SELECTOR, "#lobe circle.point"))
        framed = driver.find_element(By.ID, "frame-info").text.startswith("run ")
        if points >= min_points and framed:
            break
        time.sleep(1)
    else:
        sys.exit(f"console_screenshot: fewer than {min_points} points after 15 min")
    frame = driver.find_element(By.ID, "frame")
    w, h = frame.size["width"], frame.size["height"]
    ActionChains(driver).move_to_element_with_offset(frame, -w // 40, -h // 25).click_and_hold() \
        .move_by_offset(w // 20, h // 12).release().perform()
    end = time.monotonic() + 10
    while "mm at the sample" not in driver.find_element(By.ID, "rect-info").text:
        if time.monotonic() > end:
            break
        time.sleep(0.2)
    driver.save_screenshot(out)
    print("console_screenshot:", out)
finally:
    driver.quit()
