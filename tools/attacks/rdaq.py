"""The configuration protocol of the RemoDAQ-8300 modules in both versions (1: the password in
clear, before issue #20; 2: challenge and proof, docs/discovery.md) and a minimal Modbus/TCP
client: what the attacks (attacks.py, junk_flood.py) send. `TARGET` is the module's address."""

import hashlib
import hmac
import os
import socket
import struct

TARGET = "127.0.0.1"


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


def search_raw(port):
    """INFO of the module at `port`, in whichever protocol version answers."""
    for version in (2, 1):
        reply = exchange(header(version, 0x01, 7), port, timeout=0.3)
        if reply and reply[5] == 0x81:
            return {"proto": version, "mac": reply[12:18], "uptime": struct.unpack(">I", reply[46:50])[0]}
    return None


def scram_keys(password, salt, iterations):
    salted = hashlib.pbkdf2_hmac("sha256", password, salt, iterations)
    client_key = hmac.new(salted, b"Client Key", hashlib.sha256).digest()
    server_key = hmac.new(salted, b"Server Key", hashlib.sha256).digest()
    return client_key, hashlib.sha256(client_key).digest(), server_key


def command(sim, opcode, body, password, src="127.0.0.1"):
    """One configuration command (02 SET_NETWORK, 03 RESTART, 06 GET_ACCESS, 07 SET_ACCESS) as
    the module's protocol version wants it; the status byte of its answer (None: no answer)."""
    pw = password.encode()
    if sim.version == 1:
        reply = exchange(header(1, opcode, 9) + sim.mac + bytes([len(pw)]) + pw + body, sim.disc, src)
        return reply[14] if reply else None
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((src, 0))
        s.settimeout(1.0)
        cnonce = os.urandom(16)
        s.sendto(header(2, 0x08, 9) + sim.mac + cnonce, (TARGET, sim.disc))
        try:
            challenge = s.recv(512)
        except socket.timeout:
            return None
        snonce, salt = challenge[30:46], challenge[46:62]
        iterations = struct.unpack(">I", challenge[62:66])[0]
        client_key, stored_key, _ = scram_keys(pw, salt, iterations)
        request = bytearray(header(2, opcode, 10) + sim.mac + cnonce + snonce + bytes(32) + body)
        message = b"RDAQ discovery v2 request" + bytes(request[:46]) + bytes(request[78:])
        signature = hmac.new(stored_key, message, hashlib.sha256).digest()
        request[46:78] = bytes(a ^ b for a, b in zip(client_key, signature))
        s.sendto(bytes(request), (TARGET, sim.disc))
        try:
            return s.recv(512)[14]
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

    def close(self):
        self.s.close()


