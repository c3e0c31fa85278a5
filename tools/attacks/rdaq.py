"""The configuration protocol of the RemoDAQ-8300 modules in both versions (1: the password in
clear, before issue #20; 2: challenge and proof, docs/discovery.md) and a minimal Modbus/TCP
client: what the attacks (attacks.py, junk_flood.py) send. `TARGET` is the module's address."""

import hashlib
import hmac
import os
import socket
import struct

TARGET = "127.0.0.1"

# Whether the proofs' messages start with domain tags (protocol/src/auth.rs `domain_tag!`, issue
# #38): the modules of this tree; `RDAQ_UNTAGGED=1` for an older commit's (scripts/attacks
# --against sets it when that commit has no `domain_tag!`).
TAGGED = not os.environ.get("RDAQ_UNTAGGED")


def label(text):
    """The label of a proof's message as the module under attack makes it: a domain tag (its
    length in a byte, then the label), or the bare label of an older commit."""
    return bytes([len(text)]) + text if TAGGED else text


# --- the configuration protocol, both versions ---------------------------------------------

def header(version, opcode, rid):
    return b"RDAQ" + bytes([version, opcode]) + struct.pack(">H", rid)


def exchange(data, port, src="127.0.0.1", timeout=1.0):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((src, 0))
        s.settimeout(timeout)
        s.sendto(data, (TARGET, port))
        try:
            return s.recv(512)
        except socket.timeout:
            return None


def net_fields(b):
    """IP, mask, gateway (dotted) and Modbus port of 14 bytes of an INFO answer."""
    dotted = [".".join(str(x) for x in b[i:i + 4]) for i in (0, 4, 8)]
    return {"ip": dotted[0], "mask": dotted[1], "gateway": dotted[2], "port": struct.unpack(">H", b[12:14])[0]}


def search_raw(port, timeout=0.3, versions=(2, 1)):
    """INFO of the module at `port`, in whichever protocol version of `versions` answers (the
    same layout in both): protocol version, MAC, running and stored settings, uptime in s."""
    for version in versions:
        reply = exchange(header(version, 0x01, 7), port, timeout=timeout)
        if reply and len(reply) >= 50 and reply[5] == 0x81:
            return {"proto": version, "mac": reply[12:18], "running": net_fields(reply[18:32]),
                    "stored": net_fields(reply[32:46]), "uptime": struct.unpack(">I", reply[46:50])[0]}
    return None


# The factory credential's salt and iterations (protocol/src/auth.rs, `Credential::FACTORY`).
FACTORY_SALT = b"remodaq-factory!"
FACTORY_ITERATIONS = 4096


def password_equivalents(password, salt, iterations):
    """What a password is worth on the wire (protocol/src/auth.rs, RFC 5802): SaltedPassword =
    PBKDF2-HMAC-SHA-256(password, salt, iterations), ClientKey = HMAC(SaltedPassword, "Client
    Key"), StoredKey = SHA-256(ClientKey), ServerKey = HMAC(SaltedPassword, "Server Key")."""
    salted = hashlib.pbkdf2_hmac("sha256", password, salt, iterations)
    client_key = hmac.new(salted, b"Client Key", hashlib.sha256).digest()
    return {"SaltedPassword": salted, "ClientKey": client_key, "StoredKey": hashlib.sha256(client_key).digest(),
            "ServerKey": hmac.new(salted, b"Server Key", hashlib.sha256).digest()}


def scram_keys(password, salt, iterations):
    keys = password_equivalents(password, salt, iterations)
    return keys["ClientKey"], keys["StoredKey"], keys["ServerKey"]


def challenge_salt(answer):
    """Salt and iterations of a CHALLENGE answer (opcode 88h, docs/discovery.md); None for
    another datagram."""
    if len(answer) >= 66 and answer[:4] == b"RDAQ" and answer[5] == 0x88:
        return bytes(answer[46:62]), struct.unpack(">I", answer[62:66])[0]
    return None


def command(sim, opcode, body, password, src="127.0.0.1"):
    """One configuration command (02 SET_NETWORK, 03 RESTART, 06 GET_ACCESS, 07 SET_ACCESS) as
    the module's protocol version wants it; the status byte of its answer (None: no answer)."""
    reply = command_reply(sim, opcode, body, password, src)
    return reply[14] if reply and len(reply) > 14 else None


def command_reply(sim, opcode, body, password, src="127.0.0.1"):
    """`command`, but the whole answer (None: no answer)."""
    pw = password.encode()
    if sim.version == 1:
        return exchange(header(1, opcode, 9) + sim.mac + bytes([len(pw)]) + pw + body, sim.disc, src)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((src, 0))
        s.settimeout(1.0)
        cnonce = os.urandom(16)
        s.sendto(header(2, 0x08, 9) + sim.mac + cnonce, (TARGET, sim.disc))
        try:
            challenge = s.recv(512)
        except socket.timeout:
            return None
        snonce = challenge[30:46]
        salt, iterations = challenge_salt(challenge)
        client_key, stored_key, _ = scram_keys(pw, salt, iterations)
        request = bytearray(header(2, opcode, 10) + sim.mac + cnonce + snonce + bytes(32) + body)
        message = label(b"RDAQ discovery v2 request") + bytes(request[:46]) + bytes(request[78:])
        signature = hmac.new(stored_key, message, hashlib.sha256).digest()
        request[46:78] = bytes(a ^ b for a, b in zip(client_key, signature))
        s.sendto(bytes(request), (TARGET, sim.disc))
        try:
            return s.recv(512)
        except socket.timeout:
            return None


def net_body(ip, mask, gw, port):
    return bytes(ip) + bytes(mask) + bytes(gw) + struct.pack(">H", port)


def allow_body(networks):
    return bytes([len(networks)]) + b"".join(bytes(ip) + bytes([prefix]) for ip, prefix in networks)


# --- Modbus --------------------------------------------------------------------------------

class Modbus:
    def __init__(self, port, src="127.0.0.1"):
        self.s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.s.bind((src, 0))
        self.s.settimeout(2.0)
        self.s.connect((TARGET, port))
        self.tid = 0

    def request(self, pdu):
        self.tid = (self.tid + 1) & 0xFFFF
        self.s.sendall(struct.pack(">HHHB", self.tid, 0, len(pdu) + 1, 1) + pdu)
        head = self.recv(7)
        return self.recv(struct.unpack(">H", head[4:6])[0] - 1)

    def recv(self, n):
        out = b""
        while len(out) < n:
            chunk = self.s.recv(n - len(out))
            if not chunk:
                raise ConnectionError("closed")
            out += chunk
        return out

    def read(self, addr, n=1):
        pdu = self.request(struct.pack(">BHH", 3, addr, n))
        return list(struct.unpack(f">{n}H", pdu[2:])) if pdu[0] == 3 else None

    def write(self, addr, value):
        """True if written, else the exception code."""
        pdu = self.request(struct.pack(">BHH", 6, addr, value))
        return True if pdu[0] == 6 else pdu[1]

    def coils(self, addr, n=1):
        """Coils (function 01) as a list of 0/1; None on an exception."""
        pdu = self.request(struct.pack(">BHH", 1, addr, n))
        return [(pdu[2 + i // 8] >> (i % 8)) & 1 for i in range(n)] if pdu[0] == 1 else None

    def write_coil(self, addr, on):
        """True if written, else the exception code."""
        pdu = self.request(struct.pack(">BHH", 5, addr, 0xFF00 if on else 0))
        return True if pdu[0] == 5 else pdu[1]

    def close(self):
        self.s.close()


