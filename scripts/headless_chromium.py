"""Debian's Chromium, headless, driven by its ChromeDriver through Selenium: the browser the
console's test (tests/daemon/console_test.py) and its screenshot (scripts/console_screenshot.py)
use. scripts/install-deps.sh installs chromium, chromium-driver and python3-selenium."""
from selenium import webdriver
from selenium.webdriver.chrome.service import Service


def headless_chromium(width, height):
    opts = webdriver.ChromeOptions()
    opts.binary_location = "/usr/bin/chromium"
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
              f"--window-size={width},{height}", "--no-first-run", "--disable-extensions"):
        opts.add_argument(a)
    driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=opts)
    driver.set_page_load_timeout(30)
    return driver
