#!/usr/bin/env python3
"""The web console in a real headless browser (issue #25): Debian's chromium driven through
chromedriver by the W3C WebDriver protocol (plain HTTP and JSON, Python's standard library
only), against the host build of both modules, started here with --http.

    tools/browser/browser_test.py TARGET_DIR [SCREENSHOT_DIR [QEMU_IMAGE]]

TARGET_DIR holds firmware-8318 and firmware-8350 (the host build, e.g. target/debug);
QEMU_IMAGE, an 8350 image of the QEMU board (scripts/qemu build), runs under
qemu-system-arm (mps2-an386) as a module on a LAN: two network namespaces made here (root
only; otherwise those checks are not applicable), the module's at 192.0.2.2 (QEMU's ports
forwarded there), the browser's at 192.0.2.1, joined by a veth pair. The browser reaches the
module by its address over plain HTTP, as a maintainer's would: no secure context, so no
WebCrypto, and the page's own PBKDF2 and HMAC log in. Each
check prints `browser CHECK ... ok` or `... FAILED: why`; the last line is
`browser: N passed, M failed`. Screenshots of the pages go to SCREENSHOT_DIR (default
target/browser). Expected values come from the spec (modules.md) and the Modbus reads made
here, never from the console's own code.
"""
import base64
import json
import os
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request

FACTORY_PASSWORD = "remodaq"  # protocol/src/auth.rs, the factory credential
ELEMENT = "element-6066-11e4-a52e-4f735466cecf"  # W3C WebDriver §12: the web element identifier
# The LAN of the QEMU checks (RFC 5737's TEST-NET-1, inside namespaces made for them).
BROWSER_IP, MODULE_IP = "192.0.2.1", "192.0.2.2"


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class WebDriver:
    """A chromedriver session: the few W3C WebDriver commands these checks use."""

    def __init__(self, driver_port, window="1000,800"):
        self.base = f"http://127.0.0.1:{driver_port}"
        caps = {
            "capabilities": {
                "alwaysMatch": {
                    "browserName": "chrome",
                    "goog:chromeOptions": {
                        "binary": shutil.which("chromium") or "/usr/bin/chromium",
                        "args": ["--headless=new", "--no-sandbox", "--disable-gpu", f"--window-size={window}", "--lang=en-US"],
                    },
                }
            }
        }
        self.session = self.call("POST", "/session", caps)["sessionId"]

    def call(self, method, path, body=None):
        data = None if body is None else json.dumps(body).encode()
        req = urllib.request.Request(self.base + path, data=data, method=method, headers={"Content-Type": "application/json"})
        try:
            with urllib.request.urlopen(req, timeout=60) as r:
                return json.load(r).get("value")
        except urllib.error.HTTPError as e:
            raise RuntimeError(f"webdriver {method} {path}: {e.read().decode(errors='replace')[:300]}") from None

    def s(self, method, path, body=None):
        return self.call(method, f"/session/{self.session}{path}", body)

    def script(self, code):
        return self.s("POST", "/execute/sync", {"script": code, "args": []})

    def go(self, url):
        self.s("POST", "/url", {"url": url})

    def find(self, css, wait=10.0):
        deadline = time.time() + wait
        while True:
            found = self.s("POST", "/elements", {"using": "css selector", "value": css})
            if found:
                return found[0][ELEMENT]
            if time.time() > deadline:
                raise RuntimeError(f"no element {css!r}")
            time.sleep(0.1)

    def click(self, css):
        self.s("POST", f"/element/{self.find(css)}/click", {})

    def type(self, css, text):
        e = self.find(css)
        self.s("POST", f"/element/{e}/clear", {})
        self.s("POST", f"/element/{e}/value", {"text": text})

    def text(self, css):
        return self.s("GET", f"/element/{self.find(css)}/text")

    def wait_text(self, css, want, wait=10.0):
        """Waits until the element's text contains `want`; returns the text."""
        deadline = time.time() + wait
        text = ""
        while time.time() < deadline:
            try:
                text = self.text(css)
            except RuntimeError:
                text = ""
            if want in text:
                return text
            time.sleep(0.1)
        raise RuntimeError(f"{css!r} reads {text!r}, not {want!r}")

    def clear_message(self):
        """Empties the page's message line (`#message`), so that a wait on it after the next
        click sees only what that click brought: the page never clears it by itself, and a
        "Saved" or "Logged in" of an earlier step would otherwise satisfy the wait at once."""
        self.script('const m = document.getElementById("message"); if (m) { m.textContent = ""; m.className = ""; }')

    def click_for_message(self, css, want, wait=10.0):
        """Clicks `css` and waits for a new `want` in `#message`; returns the message."""
        self.clear_message()
        self.click(css)
        return self.wait_text("#message", want, wait)

    def rows(self):
        """The cells' texts of every table row on the page (`main#page tr`)."""
        return self.script('return Array.from(document.querySelectorAll("main#page tr"))'
                           '.map(r => Array.from(r.cells).map(c => c.textContent.trim()))')

    def screenshot(self, path):
        with open(path, "wb") as f:
            f.write(base64.b64decode(self.s("GET", "/screenshot")))

    def quit(self):
        try:
            self.s("DELETE", "")
        except Exception:
            pass


def modbus_read(modbus, function, start, count):
    """Modbus/TCP function 01 or 03 over a plain socket: the answer's data bytes."""
    with socket.create_connection(modbus, timeout=5) as s:
        s.sendall(struct.pack(">HHHBBHH", 1, 0, 6, 1, function, start, count))
        answer = s.recv(300)
    if answer[7] != function:
        raise RuntimeError(f"exception {answer[8]}")
    return answer[9 : 9 + answer[8]]


def write_coil(modbus, address, on):
    """Modbus/TCP function 05: None when written, else the exception code."""
    with socket.create_connection(modbus, timeout=5) as s:
        s.sendall(struct.pack(">HHHBBHH", 1, 0, 6, 1, 5, address, 0xFF00 if on else 0))
        answer = s.recv(300)
    return None if answer[7] == 5 else answer[8]


def read_coils(modbus, start, count):
    bits = int.from_bytes(modbus_read(modbus, 1, start, count), "little")
    return [bool(bits >> i & 1) for i in range(count)]


def read_registers(modbus, start, count):
    return list(struct.unpack(f">{count}H", modbus_read(modbus, 3, start, count)))


def wait_for_identity(web, process, seconds, what):
    """Until the console at `web` answers its identity (`process` serving it); an error after
    `seconds`, or when the process ended."""
    deadline = time.time() + seconds
    while True:
        try:
            urllib.request.urlopen(web + "/api/v1/identity", timeout=2).read()
            return
        except Exception:
            if time.time() > deadline or process.poll() is not None:
                raise RuntimeError(f"{what} did not start")
            time.sleep(0.2)


class Module:
    """A simulated module (the host build) with its web console on a free port."""

    def __init__(self, program, workdir, scenario):
        self.modbus = ("127.0.0.1", free_port())
        self.web = f"http://127.0.0.1:{free_port()}"
        name = os.path.basename(program)
        scenario_file = os.path.join(workdir, f"{name}.toml")
        with open(scenario_file, "w") as f:
            f.write(scenario)
        args = [program, "--listen", "%s:%d" % self.modbus, "--http", self.web[len("http://") :],
                "--discovery", f"127.0.0.1:{free_port()}", "--flash", os.path.join(workdir, f"{name}.flash"),
                "--scenario", scenario_file]
        self.process = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        wait_for_identity(self.web, self.process, 30, name)

    def stop(self):
        self.process.kill()
        self.process.wait()


def qemu_command(image, nic):
    """qemu-system-arm running `image` of the QEMU board as tools/qemu-e2e starts it: the board's
    bootloader (beside the image) as QEMU's kernel, the image's raw binary as the firmware
    partition's seed, its NIC `nic`."""
    bootloader = os.path.join(os.path.dirname(image), "remodaq-qemu-bootloader")
    return ["qemu-system-arm", "-M", "mps2-an386", "-nographic", "-monitor", "none", "-serial", "null",
            "-semihosting-config", "enable=on,target=native", "-nic", nic,
            "-kernel", bootloader, "-device", f"loader,file={image}.bin,addr=0x300000"]


class QemuModule:
    """An image of the QEMU board under QEMU (mps2-an386, the board's bootloader and the image as
    the firmware partition's seed, as tools/qemu-e2e starts it): in network namespace `netns`
    with Modbus and the web console at MODULE_IP's ports 8000 and 80, or, without a namespace,
    forwarded to free ports of this PC's loopback. QEMU's output goes to `log`."""

    updates = True  # the QEMU board has an update partition

    def __init__(self, image, netns=None, log=None):
        self.image = image
        if netns:
            self.modbus = (MODULE_IP, 8000)
            self.web = f"http://{MODULE_IP}"
            forwards = f"hostfwd=tcp:{MODULE_IP}:8000-:8000,hostfwd=tcp:{MODULE_IP}:80-:80"
            prefix = ["ip", "netns", "exec", netns]
        else:
            self.modbus = ("127.0.0.1", free_port())
            web = free_port()
            self.web = f"http://127.0.0.1:{web}"
            forwards = f"hostfwd=tcp:127.0.0.1:{self.modbus[1]}-:8000,hostfwd=tcp:127.0.0.1:{web}-:80"
            prefix = []
        args = prefix + qemu_command(image, f"user,id=nic0,model=lan9118,{forwards}")
        self.log = open(log or f"{image}.browser.log", "w")
        self.process = subprocess.Popen(args, stdout=self.log, stderr=subprocess.STDOUT)
        wait_for_identity(self.web, self.process, 60, f"{image} under QEMU")

    def stop(self):
        self.process.kill()
        self.process.wait()
        self.log.close()


class Checks:
    def __init__(self, browser=None, shots=None):
        self.passed = 0
        self.failed = 0
        self.not_applicable = 0
        # Where a failed check leaves a screenshot of what the browser showed.
        self.browser = browser
        self.shots = shots

    def check(self, name, f):
        try:
            f()
            self.passed += 1
            print(f"browser {name} ... ok", flush=True)
        except Exception as e:  # every failure is reported, and the next check runs
            self.failed += 1
            print(f"browser {name} ... FAILED: {e}", flush=True)
            if self.browser and self.shots:
                shot = os.path.join(self.shots, f"failed-{self.failed}.png")
                try:
                    message = self.browser.text("#message")
                    url = self.browser.s("GET", "/url")
                    self.browser.screenshot(shot)
                    print(f"browser   (the browser at {url}, its message {message!r}: {shot})", flush=True)
                except Exception:
                    pass


def every_page(checks, b, module, model, shots, shows, label=None):
    """Loads each page of `module`; each must show the texts `shows` names for it."""
    os.makedirs(shots, exist_ok=True)
    for page, wanted in shows.items():
        def load(page=page, wanted=wanted):
            b.go(f"{module.web}/#{page}")
            b.wait_text("#model", f"RemoDAQ-{model}")
            for want in wanted:
                b.wait_text("main#page", want)
            if "[object" in b.text("main#page"):
                raise RuntimeError("the page shows an object where text belongs")
            b.screenshot(os.path.join(shots, f"{model}-{page}.png"))
        checks.check(f"{label or model} page {page} loads and shows {', '.join(w.replace(chr(10), ' ') for w in wanted)}", load)


def log_in(b, password):
    """Opens the login dialog and submits `password`; `#message` is emptied first, so that a
    wait for "Logged in" sees this login's."""
    b.click("#login")
    b.type("#password", password)
    b.clear_message()
    b.click("#login-form button[value=ok]")


QEMU_CHECKS = 7  # the checks qemu_checks makes


def qemu_checks(checks, b, qemu, shots):
    """The 8350 image under QEMU, reached at its LAN address: the console on embassy-net's
    sockets, two connections at once behind the web port's SYN backlog (a page's files wait,
    never reset)."""
    every_page(checks, b, qemu, "8350", shots,
               {"status": ["Firmware\nA100", "Uptime"], "io": ["DI11", "DO5"], "settings": ["DI11", "Host watchdog"]},
               label="8350 under QEMU at its LAN address:")

    def di_states():
        b.go(f"{qemu.web}/#io")
        # The QEMU board's inputs (boards/qemu/src/digital.rs): DI3 steady high, DI0 a 1 kHz
        # square wave, the rest low.
        shown = page_matches_di(b, qemu, steady=range(1, 12), high={3})
        print(f"  the live page's DI1-DI11 under QEMU: {shown}", flush=True)
    checks.check("8350 under QEMU: the live page's DI3 (high on the QEMU board) reads on, DI1, DI2, DI4-DI11 off, "
                 "each as Modbus reads it (40301)", di_states)

    def toggle():
        b.go(f"{qemu.web}/#io")
        if b.script("return !!(window.crypto && window.crypto.subtle)"):
            raise RuntimeError(f"{qemu.web} is a secure context here: the check would not use the page's own crypto")
        wrong_then_right(b)
        toggle_do(b, qemu, 4, os.path.join(shots, "8350-io-do4-on.png"))
    checks.check("8350 under QEMU at its LAN address, plain HTTP (no WebCrypto: the page's own PBKDF2 and HMAC): "
                 "a wrong then the right password, DO4 toggled, confirmed by a Modbus read", toggle)

    # The update test images (scripts/qemu variants), signed with the repository's test key.
    images = os.path.dirname(qemu.image)

    def refused():
        # Updates need a password of one's own (docs/update.md): set on the page first.
        b.go(f"{qemu.web}/#security")
        b.type('input[aria-label="new_password"]', "correct horse battery")
        b.type('input[aria-label="repeat_password"]', "correct horse battery")
        b.click_for_message("#change-password", "Password changed", wait=60)
        b.wait_text("#login", "Log in")
        log_in(b, "correct horse battery")
        b.wait_text("#message", "Logged in", wait=60)
        b.go(f"{qemu.web}/#firmware")
        b.find("#image-file")
        # The 8318's image: uploaded whole, refused at its header, the running image kept.
        upload(b, os.path.join(images, "firmware-8350-other.rdq"))
        b.wait_text("#verdict", "not an image for this module", wait=60)
        b.screenshot(os.path.join(shots, "8350-firmware-refused.png"))
        if read_registers(qemu.modbus, 212, 1) != [0xA100]:
            raise RuntimeError("the firmware version changed")
    checks.check("8350 under QEMU: password set on the page, then the 8318's image uploaded on the firmware page: "
                 "the module's verdict \"not an image for this module\", still A100", refused)

    def updated():
        upload(b, os.path.join(images, "firmware-8350-v2.rdq"))
        b.wait_text("#verdict", "Verified and marked: A101", wait=120)
        b.screenshot(os.path.join(shots, "8350-firmware-verified.png"))
        # The bootloader swaps it in; the new image confirms itself; the page sees it back.
        b.wait_text("#verdict", "now runs firmware A101", wait=180)
        b.screenshot(os.path.join(shots, "8350-firmware-updated.png"))
        # Spec: register 40213, the firmware version.
        if read_registers(qemu.modbus, 212, 1) != [0xA101]:
            raise RuntimeError(f"Modbus reads version {read_registers(qemu.modbus, 212, 1)}")
    checks.check("8350 under QEMU: its signed A101 image uploaded on the firmware page (progress bar, the verdict), "
                 "the module restarts into it: the page and register 40213 read A101", updated)


def upload(b, path):
    """Chooses `path` in the firmware page's file field and uploads it."""
    b.s("POST", f"/element/{b.find('#image-file')}/value", {"text": path})
    b.click("#upload")


def qemu_inner(image, shots, module_ns):
    """Inside the browser's namespace: chromedriver, the image under QEMU in `module_ns`, the
    checks; the last line `browser-qemu: N passed, M failed`."""
    subprocess.run(["ip", "link", "set", "lo", "up"], check=True)
    driver_port = free_port()
    driver = subprocess.Popen(["chromedriver", f"--port={driver_port}"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    checks = Checks()
    qemu = None
    try:
        time.sleep(1)
        qemu = QemuModule(image, module_ns)
        b = WebDriver(driver_port)
        checks.browser, checks.shots = b, shots
        qemu_checks(checks, b, qemu, shots)
        b.quit()
    except Exception as e:
        print(f"browser QEMU set-up ... FAILED: {e}", flush=True)
    finally:
        if qemu:
            qemu.stop()
        driver.kill()
    failed = QEMU_CHECKS - checks.passed
    print(f"browser-qemu: {checks.passed} passed, {failed} failed", flush=True)
    return 0 if failed == 0 else 1


def qemu_on_a_lan(checks, image, shots):
    """Two namespaces and a veth pair between them (removed after), then `qemu_inner` in the
    browser's; its checks added to `checks`."""
    if os.geteuid() != 0 or not shutil.which("ip"):
        print(f"browser 8350 under QEMU on a LAN ... not applicable: needs root for network namespaces", flush=True)
        checks.not_applicable += QEMU_CHECKS
        return
    tag = str(os.getpid())
    pc, mod = f"rdaq-br-pc-{tag}", f"rdaq-br-mod-{tag}"
    setup = [
        ["ip", "netns", "add", pc], ["ip", "netns", "add", mod],
        ["ip", "link", "add", "brpc0", "netns", pc, "type", "veth", "peer", "name", "brmod0", "netns", mod],
        ["ip", "-n", pc, "addr", "add", f"{BROWSER_IP}/24", "dev", "brpc0"],
        ["ip", "-n", mod, "addr", "add", f"{MODULE_IP}/24", "dev", "brmod0"],
        ["ip", "-n", pc, "link", "set", "brpc0", "up"], ["ip", "-n", mod, "link", "set", "brmod0", "up"],
        ["ip", "-n", mod, "link", "set", "lo", "up"],
    ]
    try:
        for command in setup:
            subprocess.run(command, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        os.makedirs(shots, exist_ok=True)
        inner = subprocess.run(["ip", "netns", "exec", pc, sys.executable, os.path.abspath(__file__), "--qemu-inner",
                                image, shots, mod], stdout=subprocess.PIPE, text=True, timeout=600)
        counted = False
        for line in inner.stdout.splitlines():
            if line.startswith("browser-qemu: "):
                words = line.split()
                checks.passed += int(words[1])
                checks.failed += int(words[3])
                counted = True
            else:
                print(line, flush=True)
        if not counted:
            raise RuntimeError(f"the checks inside the namespace ended without a count (exit {inner.returncode})")
    except Exception as e:
        print(f"browser QEMU on a LAN ... FAILED: {e}", flush=True)
        checks.failed += QEMU_CHECKS
    finally:
        subprocess.run(["ip", "netns", "del", pc], stderr=subprocess.DEVNULL)
        subprocess.run(["ip", "netns", "del", mod], stderr=subprocess.DEVNULL)


# The 8318 scenario's channel 0 (41.276 mV at the terminals, type K, the cold junction at
# 25 °C): NIST ITS-90's type K table (modules/8318/tests/reference/nist-its90-tables.tab) gives
# E(25 °C) = 1.000 mV, so the hot junction's emf is 42.276 mV, between 42.247 mV (1025 °C) and
# 42.286 mV (1026 °C): 1025.74 °C. The table's 3 decimals are worth 0.013 °C, one count of the
# type K range (-250 .. 1400 °C, spec §2.2-2.3) 0.025 °C.
CH0_CELSIUS = 1025.74
CH0_TOLERANCE = 0.1
# Type K's range (spec §2.2) and the linear mapping of its codes (§2.3).
TYPE_K = (-250.0, 1400.0)


def page_matches_di(b, module, steady, high, wait=10.0):
    """Waits until the live page's DI rows show, for each DI in `steady`, "on" exactly when
    register 40301 (spec §3.1: every DI, bit n = DIn) has its bit set, and those in `high` are
    on; returns the states shown. An error naming both readings otherwise."""
    deadline = time.time() + wait
    while True:
        shown = {int(r[0][2:]): r[1] for r in b.rows() if len(r) >= 2 and r[0][:2] == "DI" and r[0][2:].isdigit()}
        bits = read_registers(module.modbus, 0x12C, 1)[0]
        modbus = {n: "on" if bits >> n & 1 else "off" for n in steady}
        page = {n: shown.get(n) for n in steady}
        wanted_high = all(modbus[n] == "on" for n in high)
        if page == modbus and wanted_high:
            return page
        if time.time() > deadline:
            raise RuntimeError(f"the page shows DI states {page}, Modbus reads {bits:04x}h: {modbus} "
                               f"(DI{sorted(high)} high in the scenario)")
        time.sleep(0.2)


def page_matches_8318(b, module, wait=10.0):
    """Waits until the live page's channel 0 row shows the scenario's temperature and the
    value and raw code that register 40001 holds (within 2 counts: the page and the read are
    not taken at the same instant); returns the row."""
    lo, hi = TYPE_K
    deadline = time.time() + wait
    why = "no channel 0 row"
    while True:
        row = next((r for r in b.rows() if len(r) >= 4 and r[0] == "0"), None)
        raw = read_registers(module.modbus, 0, 1)[0]
        celsius = lo + raw * (hi - lo) / 65535
        if row:
            try:
                value, unit = row[1].split(" ", 1)
                value = float(value)
                page_raw = int(row[3])
                if unit != "°C":
                    why = f"channel 0 reads {row[1]!r}: not in °C"
                elif abs(value - CH0_CELSIUS) > CH0_TOLERANCE:
                    why = f"channel 0 reads {row[1]!r}, the scenario gives {CH0_CELSIUS} ± {CH0_TOLERANCE} °C"
                elif abs(value - celsius) > 2 * (hi - lo) / 65535 or abs(page_raw - raw) > 2:
                    why = f"channel 0 reads {row[1]!r} (raw {page_raw}), Modbus {raw} = {celsius:.3f} °C"
                else:
                    return row
            except ValueError:
                why = f"channel 0's row {row!r} is not a value, a unit and a raw code"
        if time.time() > deadline:
            raise RuntimeError(why)
        time.sleep(0.2)


def wrong_then_right(b):
    """Logs in with a wrong password (refused), then the factory one."""
    log_in(b, "not the password")
    b.wait_text("#login-error", "Wrong password")
    b.type("#password", FACTORY_PASSWORD)
    b.click_for_message("#login-form button[value=ok]", "Logged in")


def toggle_do(b, module, n, shot):
    """DO`n` switched on by its button on the live page; a Modbus read must show it on alone."""
    b.wait_text(f"button[aria-label=DO{n}]", "off")
    b.click(f"button[aria-label=DO{n}]")
    b.wait_text(f"button[aria-label=DO{n}]", "on")
    # Spec §3.1: DO0-DO5 at coils 10h-15h.
    coils = read_coils(module.modbus, 0x10, 6)
    if coils != [i == n for i in range(6)]:
        raise RuntimeError(f"Modbus reads the DOs {coils}")
    b.screenshot(shot)


def main():
    if sys.argv[1:2] == ["--qemu-inner"]:
        return qemu_inner(*sys.argv[2:5])
    target = sys.argv[1] if len(sys.argv) > 1 else "target/debug"
    shots = sys.argv[2] if len(sys.argv) > 2 else "target/browser"
    qemu_image = sys.argv[3] if len(sys.argv) > 3 else None
    os.makedirs(shots, exist_ok=True)
    driver_port = free_port()
    driver = subprocess.Popen(["chromedriver", f"--port={driver_port}"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    checks = Checks()
    work = tempfile.mkdtemp(prefix="rdaq-browser-")
    modules = []
    try:
        time.sleep(1)
        m8350 = Module(os.path.join(target, "firmware-8350"), work, "[di0]\nsquare_hz = 5.0\n[di1]\nlevel = true\n")
        m8318 = Module(os.path.join(target, "firmware-8318"), work,
                       "cjc_celsius = 25.0\n[ch0]\nmillivolts = 41.276\n[ch1]\nvolts = 1.2\n[ch3]\nopen = true\n")
        modules += [m8350, m8318]
        b = WebDriver(driver_port)
        checks.browser, checks.shots = b, shots

        # 8350: every page loads.
        # What each page must show (spec: firmware version A100h, 12 DI, 6 DO; extensions §3).
        every_page(checks, b, m8350, "8350", shots,
                   {"status": ["Firmware\nA100", "Uptime"], "io": ["DI11", "DO5"], "settings": ["DI11", "Host watchdog"],
                    "network": ["Stored settings", "In force now"], "security": ["Modbus write allow-list", "Log in to see"],
                    "firmware": ["Firmware\nA100", "no firmware updates here"]})

        def log_in_twice():
            b.go(f"{m8350.web}/#io")
            wrong_then_right(b)
            b.wait_text("#login", "Log out")
        checks.check("8350 log in: a wrong password refused, then the right one", log_in_twice)

        def toggle():
            b.go(f"{m8350.web}/#io")
            toggle_do(b, m8350, 2, os.path.join(shots, "8350-io-do2-on.png"))
        checks.check("8350 DO2 toggled on the live page, confirmed by a Modbus read", toggle)

        def di_states():
            b.go(f"{m8350.web}/#io")
            # The scenario: DI1 steady high, DI0 a 5 Hz square wave, the rest low.
            shown = page_matches_di(b, m8350, steady=range(1, 12), high={1})
            b.screenshot(os.path.join(shots, "8350-io-di.png"))
            print(f"  the live page's DI1-DI11: {shown}", flush=True)
        checks.check("8350 live page: DI1 (high in the scenario) reads on, DI2-DI11 off, each as Modbus reads "
                     "it (40301)", di_states)

        def chinese():
            b.go(f"{m8350.web}/#io")
            b.click("#lang")
            b.wait_text("nav", "实时")
            b.wait_text("main#page", "数字输入")
            b.screenshot(os.path.join(shots, "8350-io-zh.png"))
            b.click("#lang")
            b.wait_text("nav", "Live I/O")
        checks.check("8350 language switch to Simplified Chinese and back", chinese)

        def phone():
            # A phone's screen (390 x 844 CSS pixels): the widest page, the 8350's settings, fits
            # its width (a wide table scrolls inside itself).
            b.s("POST", "/window/rect", {"width": 390, "height": 844})
            try:
                for page in ["io", "settings"]:
                    b.go(f"{m8350.web}/#{page}")
                    b.wait_text("main#page", "DO5")
                    wide = b.script("return [document.documentElement.scrollWidth, window.innerWidth]")
                    if wide[0] > wide[1]:
                        raise RuntimeError(f"#{page} is {wide[0]} px wide on a {wide[1]} px screen")
                    b.screenshot(os.path.join(shots, f"8350-{page}-phone.png"))
            finally:
                b.s("POST", "/window/rect", {"width": 1000, "height": 800})
        checks.check("8350 pages on a phone-sized screen: nothing wider than the screen", phone)

        def password():
            # The factory password may not set the allow-list (docs/security.md): refused,
            # then the password changed on the page, and the new one logs in.
            b.go(f"{m8350.web}/#security")
            b.type('input[aria-label="networks"]', "192.0.2.0/24")
            b.click_for_message("#save-access", "Set a password of your own first")
            b.type('input[aria-label="new_password"]', "correct horse battery")
            b.type('input[aria-label="repeat_password"]', "correct horse battery")
            b.click_for_message("#change-password", "Password changed", wait=30)
            b.wait_text("#login", "Log in")
            log_in(b, FACTORY_PASSWORD)
            b.wait_text("#login-error", "Wrong password")
            b.type("#password", "correct horse battery")
            b.click_for_message("#login-form button[value=ok]", "Logged in", wait=30)
        checks.check("8350 password changed on the security page (the factory one may not set the allow-list); "
                     "the old one refused, the new one logs in", password)

        def allow_list():
            # Extensions §4: a list without this PC's network refuses its Modbus writes
            # (exception 01); emptied, writes are served again.
            b.go(f"{m8350.web}/#security")
            b.type('input[aria-label="networks"]', "192.0.2.0/24, 10.9.8.7")
            # Each save waits for its own "Saved" (the message line emptied before the click).
            b.click_for_message("#save-access", "Saved")
            # Drawn again from the module's answer: the bare address as /32.
            shown, deadline = "", time.time() + 10
            while shown != "192.0.2.0/24, 10.9.8.7/32" and time.time() < deadline:
                time.sleep(0.1)
                shown = b.script('const e = document.querySelector(\'input[aria-label="networks"]\'); return e ? e.value : ""')
            if shown != "192.0.2.0/24, 10.9.8.7/32":
                raise RuntimeError(f"the page shows the list {shown!r}")
            b.screenshot(os.path.join(shots, "8350-security-allow-list.png"))
            if write_coil(m8350.modbus, 0x10, False) != 1:
                raise RuntimeError("a Modbus write from outside the list was not refused with exception 01")
            b.type('input[aria-label="networks"]', "")
            # Each save waits for its own "Saved" (the message line emptied before the click).
            b.click_for_message("#save-access", "Saved")
            if write_coil(m8350.modbus, 0x10, False) is not None:
                raise RuntimeError("a Modbus write was refused with the list emptied")
        checks.check("8350 allow-list set on the security page: a Modbus write from outside it refused "
                     "(exception 01), served again once emptied", allow_list)

        def network():
            b.go(f"{m8350.web}/#network")
            b.type('input[aria-label="ip"]', "192.0.2.20")
            b.click_for_message("main#page button", "Saved")
            b.wait_text("main#page", "take effect after a restart")
            stored = json.loads(urllib.request.urlopen(m8350.web + "/api/v1/network", timeout=5).read())["stored"]
            if stored["ip"] != "192.0.2.20":
                raise RuntimeError(f"the module stored {stored}")
            b.screenshot(os.path.join(shots, "8350-network-stored.png"))
        checks.check("8350 network address changed on the network page: stored, a restart asked for", network)

        # 8318: pages, then the input type changed on the settings page.
        # The scenario's channel 3 is an open thermocouple (extensions §2: status open).
        every_page(checks, b, m8318, "8318", shots,
                   {"status": ["Firmware\nA100", "Uptime"], "io": ["open", "°C"], "settings": ["Input type", "Cold junction: 25"],
                    "network": ["Stored settings", "In force now"], "security": ["Modbus write allow-list"]})

        def channel_values():
            b.go(f"{m8318.web}/#io")
            shown = page_matches_8318(b, m8318)
            b.screenshot(os.path.join(shots, "8318-io-values.png"))
            print(f"  the live page's channel 0: {shown}", flush=True)
        checks.check(f"8318 live page: channel 0 (41.276 mV, type K, cold junction 25 °C) reads {CH0_CELSIUS} °C "
                     "(NIST ITS-90), its value and raw code as Modbus reads them (40001)", channel_values)

        def input_type():
            b.go(f"{m8318.web}/#io")
            # Factory type K (spec §2.2): °C.
            b.wait_text("main#page", "°C")
            log_in(b, FACTORY_PASSWORD)
            b.wait_text("#message", "Logged in")
            b.go(f"{m8318.web}/#settings")
            b.click('select[aria-label="inputs/type"]')
            b.click_for_message('select[aria-label="inputs/type"] option[value="5"]', "Saved")
            # Spec §2.1: 40201 holds the type code; 05h is ±2.5 V.
            if read_registers(m8318.modbus, 0xC8, 1) != [5]:
                raise RuntimeError(f"40201 reads {read_registers(m8318.modbus, 0xC8, 1)}")
            b.go(f"{m8318.web}/#io")
            # Channel 1 at 1.2 V reads 1200 mV (one count of ±2.5 V is 0.076 mV), once the next
            # sample (10 Hz) is taken with the new type.
            text = b.wait_text("main#page", "1200.0")
            if "°C" in text:
                raise RuntimeError(f"the live page reads {text!r}")
            b.screenshot(os.path.join(shots, "8318-io-volts.png"))
        checks.check("8318 input type changed to ±2.5 V: 40201 reads 05h, the values turn to mV", input_type)

        b.quit()
        b = checks.browser = None
        if qemu_image:
            qemu_on_a_lan(checks, os.path.abspath(qemu_image), os.path.join(os.path.abspath(shots), "qemu"))
    except Exception as e:
        checks.failed += 1
        print(f"browser set-up ... FAILED: {e}", flush=True)
    finally:
        for m in modules:
            m.stop()
        driver.kill()
        shutil.rmtree(work, ignore_errors=True)
    na = f", {checks.not_applicable} not applicable" if checks.not_applicable else ""
    print(f"browser: {checks.passed} passed, {checks.failed} failed{na}")
    return 0 if checks.failed == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
