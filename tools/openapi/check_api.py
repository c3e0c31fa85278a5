#!/usr/bin/env python3
"""Every answer of the web console's API against docs/openapi.yaml (issue #25: "every response
follows it"), on the host build of both models started here with --http.

    tools/openapi/check_api.py TARGET_DIR

TARGET_DIR holds firmware-8318 and firmware-8350 (the host build, e.g. target/debug). The
requests cover every operation of the file (a check fails for an operation never exercised)
with their answers good and bad: reads, a login (wrong, then right: the page's computation,
docs/web.md, with Python's hashlib and hmac), signed writes taken and refused, unsigned,
foreign and rebound requests. Each answer's status must be one the file lists for that
operation, and its body must follow the schema the file gives for that status (OpenAPI 3.0
Schema Objects: type, nullable, enum, pattern, minimum, maximum, required, properties,
additionalProperties, items, oneOf, $ref). Every signed write the module takes (204) is read
back: over Modbus at the address the spec gives the field (/work/shared/spec: modules.md §2.1,
§3.1, §3.2; extensions.md §2, §3), and by a GET of the resource, field by field, so that a write
that lands on another field, or changes nothing, fails its operation. One check per operation:
`openapi METHOD PATH ... ok`; the last line `openapi: N passed, M failed`.
"""
import hashlib
import hmac
import json
import os
import re
import socket
import subprocess
import sys
import tempfile
import time

try:
    import yaml
except ImportError:  # a fresh machine: PyYAML from PyPI
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "pyyaml"], check=True)
    import yaml

HERE = os.path.dirname(os.path.abspath(__file__))
SPEC = os.path.join(HERE, "..", "..", "docs", "openapi.yaml")
sys.path.insert(0, os.path.join(HERE, "..", "browser"))
from browser_test import (  # noqa: E402
    FACTORY_PASSWORD, Module, QemuModule, read_coils, read_registers)

# Where each writable field of a resource is, as the spec gives it (never as the module's own
# table says): (model, resource, field) -> (Modbus table, address of item 0, addresses from one
# item to the next, registers of its value). modules.md §2.1 (8318), §3.1 and §3.2 (8350);
# extensions.md §2 (8318 open-input value), §3 (8350 host watchdog).
SPEC_ADDRESSES = {
    ("8350", "di", "mode"): ("register", 0x100, 1, 1),
    ("8350", "di", "counting"): ("coil", 0x20, 4, 1),
    ("8350", "di", "clear"): ("coil", 0x21, 4, 1),
    ("8350", "di", "overflow"): ("coil", 0x22, 4, 1),
    ("8350", "di", "latch"): ("coil", 0x23, 4, 1),
    ("8350", "do", "state"): ("coil", 0x10, 1, 1),
    ("8350", "do", "mode"): ("register", 0x110, 1, 1),
    ("8350", "do", "low_width"): ("register", 0x18, 2, 2),
    ("8350", "do", "high_width"): ("register", 0x24, 2, 2),
    ("8350", "do", "pulses"): ("register", 0x30, 2, 2),
    ("8350", "do", "extra_pulses"): ("register", 0x3C, 2, 2),
    ("8350", "watchdog", "timeout"): ("register", 0x130, 0, 1),
    ("8350", "watchdog", "safe_values"): ("register", 0x131, 0, 1),
    ("8350", "watchdog", "mode"): ("register", 0x132, 0, 1),
    ("8350", "watchdog", "tripped"): ("register", 0x133, 0, 1),
    ("8350", "watchdog", "power_on_values"): ("register", 0x134, 0, 1),
    ("8318", "inputs", "type"): ("register", 0xC8, 0, 1),
    ("8318", "inputs", "cjc_offset"): ("register", 0xD7, 0, 1),
    ("8318", "inputs", "enable_mask"): ("register", 0xDC, 0, 1),
    ("8318", "inputs", "open_value"): ("register", 0xE8, 0, 1),
}

# The register value of each name (the names are docs/openapi.yaml's, the values the spec's):
# DI modes modules.md §3.2 (0 normal, 1 counter, 2 low-to-high latch, 3 high-to-low latch,
# 4 frequency), DO modes §3.2 (0 normal, 1 pulse output), open-input value extensions §2
# (0 upscale, 1 downscale).
SPEC_NAMES = {
    ("di", "mode"): {"normal": 0, "counter": 1, "latch rising": 2, "latch falling": 3, "frequency": 4},
    ("do", "mode"): {"normal": 0, "pulse": 1},
    ("inputs", "open_value"): {"upscale": 0, "downscale": 1},
}


def tag(label):
    """A domain tag (protocol/src/auth.rs `domain_tag!`): the label's length in a byte, then the label."""
    return bytes([len(label)]) + label


def spec_words(resource, field, value, words):
    """The register (or coil) values `value` of `field` is written as, by the spec."""
    if isinstance(value, bool):
        return [int(value)]
    if (resource, field) in SPEC_NAMES:
        return [SPEC_NAMES[(resource, field)][value]]
    if field == "cjc_offset":  # modules.md §2.4: 0.01 °C, negative as raw - 10000h
        return [round(value * 100) & 0xFFFF]
    if words == 2:  # modules.md §3.2: 32-bit values low word first
        return [value & 0xFFFF, value >> 16]
    return [value]


def exchange(web, method, target, headers=(), body=b"", host=None):
    """One request on its own connection; (status, body bytes)."""
    host = host or f"{web[0]}:{web[1]}"
    head = f"{method} {target} HTTP/1.1\r\nHost: {host}\r\nContent-Length: {len(body)}\r\n"
    head += "".join(f"{k}: {v}\r\n" for k, v in headers) + "\r\n"
    with socket.create_connection(web, timeout=10) as s:
        s.sendall(head.encode() + body)
        data = b""
        while chunk := s.recv(4096):
            data += chunk
    head, _, rest = data.partition(b"\r\n\r\n")
    status = int(head.split(b" ")[1]) if head.startswith(b"HTTP/1.1 ") else 0
    return status, rest


class Schemas:
    def __init__(self, spec):
        self.spec = spec

    def deref(self, node):
        while isinstance(node, dict) and "$ref" in node:
            at = self.spec
            for part in node["$ref"].lstrip("#/").split("/"):
                at = at[part]
            node = at
        return node

    def check(self, schema, value, where="$"):
        """The first way `value` breaks `schema`, or None."""
        schema = self.deref(schema)
        if value is None:
            return None if schema.get("nullable") else f"{where}: null where it may not be"
        if "oneOf" in schema:
            fits = [s for s in schema["oneOf"] if self.check(s, value, where) is None]
            return None if len(fits) == 1 else f"{where}: {value!r} fits {len(fits)} of oneOf"
        kind = schema.get("type")
        python = {"object": dict, "array": list, "string": str, "boolean": bool}
        if kind in python and not isinstance(value, python[kind]):
            return f"{where}: {value!r} is not {kind}"
        if kind == "integer" and (isinstance(value, bool) or not isinstance(value, int)):
            return f"{where}: {value!r} is not an integer"
        if kind == "number" and (isinstance(value, bool) or not isinstance(value, (int, float))):
            return f"{where}: {value!r} is not a number"
        if "enum" in schema and value not in schema["enum"]:
            return f"{where}: {value!r} not in {schema['enum']}"
        if "pattern" in schema and not re.search(schema["pattern"], value):
            return f"{where}: {value!r} does not match {schema['pattern']}"
        if "minimum" in schema and value < schema["minimum"]:
            return f"{where}: {value} below {schema['minimum']}"
        if "maximum" in schema and value > schema["maximum"]:
            return f"{where}: {value} above {schema['maximum']}"
        if kind == "object":
            for name in schema.get("required", []):
                if name not in value:
                    return f"{where}: {name} missing"
            properties = schema.get("properties", {})
            for name, v in value.items():
                if name in properties:
                    broken = self.check(properties[name], v, f"{where}.{name}")
                    if broken:
                        return broken
                elif schema.get("additionalProperties", True) is False:
                    return f"{where}: {name} is not in the schema"
        if kind == "array":
            for i, v in enumerate(value):
                broken = self.check(schema.get("items", {}), v, f"{where}[{i}]")
                if broken:
                    return broken
        return None


class Api:
    """The operations of the file, and what was seen of each."""

    def __init__(self, spec):
        self.spec = spec
        self.schemas = Schemas(spec)
        self.seen = {}  # (METHOD, template) -> [problems], one entry per answer

    def template(self, path):
        for template in self.spec["paths"]:
            pattern = "^" + re.sub(r"\{[^}]+\}", "[^/]+", template) + "$"
            if re.match(pattern, path):
                return template
        return None

    def wrong(self, method, target, problem):
        path = target.split("?")[0][len("/api/v1"):]
        self.seen.setdefault((method, self.template(path) or path), []).append(f"{method} {target}: {problem}")

    def answer(self, method, target, status, body):
        """Checks one answer against the file."""
        path = target.split("?")[0][len("/api/v1"):]
        template = self.template(path)
        op = template and self.spec["paths"][template].get(method.lower())
        key = (method, template or path)
        problems = self.seen.setdefault(key, [])
        if not op:
            problems.append(f"{method} {target}: no such operation in the file")
            return
        response = op["responses"].get(str(status)) or op["responses"].get("default")
        if response is None:
            problems.append(f"{method} {target}: status {status} is not listed ({body[:80]!r})")
            return
        response = self.schemas.deref(response)
        content = response.get("content", {}).get("application/json")
        if content is None:
            if body:
                problems.append(f"{method} {target}: {status} has a body the file does not list: {body[:80]!r}")
            return
        try:
            value = json.loads(body)
        except ValueError:
            problems.append(f"{method} {target}: {status} body is no JSON: {body[:80]!r}")
            return
        broken = self.schemas.check(content["schema"], value)
        if broken:
            problems.append(f"{method} {target} {status}: {broken}")


class Client:
    """Requests to one module, every answer checked; a login as the page makes it."""

    def __init__(self, api, module):
        host, port = module.web[len("http://"):].rsplit(":", 1)
        self.api, self.web, self.modbus = api, (host, int(port)), module.modbus
        self.session = None
        self.model = json.loads(exchange(self.web, "GET", "/api/v1/identity")[1])["model"]
        # Whether the module takes updates (an image of a board with an update partition).
        self.updates = getattr(module, "updates", False)

    def call(self, method, target, value=None, headers=(), raw=None, host=None, expect=200):
        """The request; its answer checked against the file, and its status against `expect`
        (what the spec and docs/web.md say the module answers)."""
        body = raw if raw is not None else (b"" if value is None else json.dumps({"value": value}).encode())
        status, answer = exchange(self.web, method, target, headers, body, host)
        self.api.answer(method, target, status, answer)
        if expect is not None and status != expect:
            self.api.wrong(method, target, f"answered {status}, {expect} expected: {answer[:80]!r}")
        return status, answer

    def signed(self, method, target, value=None, extra=(), expect=204, raw=None):
        body = raw if raw is not None else (b"" if value is None else json.dumps({"value": value}).encode())
        session, key, counter = self.session
        counter += 1
        self.session = (session, key, counter)
        message = tag(b"RDAQ web request\n") + f"{method}\n{target}\n{counter}\n".encode() + body
        signature = hmac.new(key, message, hashlib.sha256).hexdigest()
        headers = [("X-RDAQ-Session", session), ("X-RDAQ-Counter", str(counter)), ("X-RDAQ-Signature", signature)]
        status, answer = self.call(method, target, headers=headers + list(extra), raw=body, expect=expect)
        if method == "PUT" and status == 204:
            try:
                problem = self.read_back(target, json.loads(body))
            except Exception as e:  # a read that failed is a failed read-back
                problem = f"read back: {e!r}"
            if problem:
                self.api.wrong(method, target, problem)
        return status, answer

    def get(self, target, signed=False):
        """A GET's JSON (signed where the resource needs a session)."""
        status, answer = (self.signed if signed else self.call)("GET", target, expect=200)
        return json.loads(answer) if status == 200 else None

    def read_back(self, target, body):
        """What is wrong with the write of `body` to `target` once read back, or None: the
        field's registers read over Modbus at the spec's address, and the resource's GET."""
        parts = target[len("/api/v1/"):].split("/")
        if parts[0] in ("registers", "coils"):
            address, value = int(parts[1]), body["value"]
            if parts[0] == "registers":
                modbus, words = read_registers(self.modbus, address, 1), [value]
            else:
                modbus, words = [int(b) for b in read_coils(self.modbus, address, 1)], [int(value)]
            shown = self.get(f"/api/v1/{parts[0]}/{address}")
            if modbus != words or shown != {"values": [value]}:
                return f"wrote {value!r}, Modbus reads {modbus} at {address}, the GET shows {shown}"
            return None
        if parts == ["network"]:
            stored = (self.get("/api/v1/network") or {}).get("stored")
            return None if stored == body else f"wrote {body}, stored {stored}"
        if parts == ["access"]:
            shown = (self.get("/api/v1/access", signed=True) or {}).get("networks")
            want = [n if "/" in n else n + "/32" for n in body["networks"]]  # a bare address is /32
            return None if shown == want else f"wrote {body['networks']}, shown {shown}"
        if parts == ["mqtt"]:
            shown = self.get("/api/v1/mqtt", signed=True) or {}
            # Whether a CA and credentials are stored is shown beside the settings, read-only.
            settings = {k: v for k, v in shown.items() if k not in ("ca", "credentials")}
            return None if settings == body else f"wrote {body}, shown {shown}"
        if parts == ["mqtt", "ca"]:
            stored = (self.get("/api/v1/mqtt", signed=True) or {}).get("ca")
            return None if stored == bool(body["pem"]) else f"wrote a PEM of {len(body['pem'])} characters, ca {stored}"
        if parts == ["mqtt", "credentials"]:
            return None  # sealed: read back by put_mqtt_credentials's callers (GET /mqtt's flag)
        if parts == ["password"]:
            return None  # read back by logging in with the new password (change_password's callers)
        resource, item, field = (parts[0], None, parts[1]) if len(parts) == 2 else parts
        value = body["value"]
        where = SPEC_ADDRESSES.get((self.model, resource, field))
        if where is None:
            return f"no spec address to read {resource}.{field} back at"
        table, base, stride, words = where
        address = base + stride * int(item or 0)
        if table == "register":
            modbus = read_registers(self.modbus, address, words)
        else:
            modbus = [int(b) for b in read_coils(self.modbus, address, words)]
        if field == "clear":
            # modules.md §3.1: "write 1 clears; reads 0": the counter is back at 0 (the square
            # wave on DI0 counts on, one edge every 200 ms).
            counter = read_registers(self.modbus, 2 * int(item), 2)
            shown = self.get(f"/api/v1/{resource}/{item}")["counter"]
            if modbus != [0] or counter[1] != 0 or counter[0] > 1 or shown > 1:
                return f"after the clear: coil {modbus}, Modbus counter {counter}, the GET shows {shown}"
            return None
        want = spec_words(resource, field, value, words)
        if modbus != want:
            return f"wrote {value!r}: Modbus reads {modbus} at {address:04X}h, the spec's {want}"
        shown = self.get(f"/api/v1/{resource}" + (f"/{item}" if item is not None else ""))
        seen = shown.get(field)
        if field == "type":
            seen = seen.get("code")
        if seen != value:
            return f"wrote {value!r}, the GET shows {field} {seen!r}"
        if field == "enable_mask":  # modules.md §2.1: bit n = channel n
            enabled = [ch["enabled"] for ch in self.get("/api/v1/channels")["channels"]]
            if enabled != [bool(value >> n & 1) for n in range(8)]:
                return f"mask {value:08b}: the channels show enabled {enabled}"
        return None

    def log_in(self, password):
        """docs/web.md, "Authentication": SCRAM-SHA-256's keys, the web login's message."""
        status, c = self.call("POST", "/api/v1/session/challenge")
        c = json.loads(c)
        salted = hashlib.pbkdf2_hmac("sha256", password.encode(), bytes.fromhex(c["salt"]), c["iterations"], 32)
        client_key = hmac.new(salted, b"Client Key", hashlib.sha256).digest()
        stored_key = hashlib.sha256(client_key).digest()
        _, identity = exchange(self.web, "GET", "/api/v1/identity")
        mac = bytes.fromhex(json.loads(identity)["mac"])
        page_nonce = os.urandom(16)
        message = tag(b"RDAQ web login") + mac + bytes.fromhex(c["nonce"]) + page_nonce
        proof = bytes(a ^ b for a, b in zip(client_key, hmac.new(stored_key, message, hashlib.sha256).digest()))
        body = json.dumps({"nonce": c["nonce"], "page_nonce": page_nonce.hex(), "proof": proof.hex()}).encode()
        status, s = self.call("POST", "/api/v1/session", raw=body, headers=[("Content-Type", "application/json")],
                              expect=None)
        if status != 200:
            return status
        key = hmac.new(client_key, tag(b"RDAQ web session") + bytes.fromhex(c["nonce"]) + page_nonce, hashlib.sha256).digest()
        self.session = (json.loads(s)["session"], key, 0)
        return status


def exercise_8350(c):
    c.call("GET", "/api/v1/identity")
    c.call("GET", "/api/v1/identity", host="attacker.example", expect=421)  # DNS rebinding
    if c.log_in("not the password") != 401:
        raise RuntimeError("a wrong password logged in")
    if c.log_in(FACTORY_PASSWORD) != 200:
        raise RuntimeError("the factory password did not log in")
    c.call("GET", "/api/v1/registers/0?count=10")
    c.call("GET", "/api/v1/registers/0?count=126", expect=400)  # Modbus's 125 at most
    c.call("GET", "/api/v1/registers/0?count=x", expect=400)
    c.signed("PUT", "/api/v1/registers/0", 1, expect=404)  # 40001 is not writable (spec §3.1)
    c.signed("PUT", "/api/v1/registers/304", 50)  # host watchdog timeout (extensions §3), 5 s
    c.signed("PUT", "/api/v1/registers/304", 0)
    c.call("GET", "/api/v1/coils/16?count=6")
    c.call("GET", "/api/v1/coils/16?count=151", expect=400)
    c.signed("PUT", "/api/v1/coils/16", True)
    c.call("PUT", "/api/v1/coils/16", False, expect=401)  # unsigned
    c.signed("PUT", "/api/v1/coils/16", False, extra=[("Origin", "http://attacker.example")], expect=403)
    c.signed("PUT", "/api/v1/coils/16", "on", expect=400)  # not a boolean
    for target, status in [("/api/v1/di", 200), ("/api/v1/di/0", 200), ("/api/v1/di/12", 404), ("/api/v1/do", 200),
                           ("/api/v1/do/5", 200), ("/api/v1/do/6", 404), ("/api/v1/watchdog", 200),
                           ("/api/v1/diagnostics", 200), ("/api/v1/channels", 404), ("/api/v1/channels/0", 404),
                           ("/api/v1/inputs", 404)]:
        c.call("GET", target, expect=status)
    c.signed("PUT", "/api/v1/di/0/mode", "counter")
    c.signed("PUT", "/api/v1/di/0/mode", "sideways", expect=422)
    c.signed("PUT", "/api/v1/di/0/counter", 5, expect=405)  # read-only
    c.signed("PUT", "/api/v1/di/12/mode", "normal", expect=404)
    # DI0 counts its 5 Hz square wave; a clear then brings its counter back to 0.
    c.signed("PUT", "/api/v1/di/0/counting", True)
    deadline = time.time() + 5
    while c.get("/api/v1/di/0")["counter"] < 3 and time.time() < deadline:
        time.sleep(0.1)
    if c.get("/api/v1/di/0")["counter"] < 3:  # else the clear's read-back would prove nothing
        c.api.wrong("PUT", "/api/v1/di/0/counting", "DI0 did not count its 5 Hz square wave in 5 s")
    # Stopped first, so that the clear's read-back sees 0 however fast DI0 counts (the QEMU
    # board's DI0 is a 1 kHz square wave).
    c.signed("PUT", "/api/v1/di/0/counting", False)
    c.signed("PUT", "/api/v1/di/0/clear", True)
    c.signed("PUT", "/api/v1/do/0/state", True)
    c.signed("PUT", "/api/v1/do/1/mode", "pulse")
    c.signed("PUT", "/api/v1/do/1/high_width", 70000)
    c.signed("PUT", "/api/v1/do/1/low_width", 0, expect=422)
    for target in ["/api/v1/di/0", "/api/v1/do/1", "/api/v1/di"]:  # as written
        c.call("GET", target)
    c.signed("PUT", "/api/v1/watchdog/timeout", 6001, expect=422)  # 600 s at most
    # Each field with a value of its own, so that a write landing on another field shows.
    c.signed("PUT", "/api/v1/watchdog/safe_values", 0b000011)
    c.signed("PUT", "/api/v1/watchdog/power_on_values", 0b101000)
    c.signed("PUT", "/api/v1/watchdog/mode", 2)  # automatic clear, fed by any request
    c.signed("PUT", "/api/v1/watchdog/timeout", 6000)
    c.signed("PUT", "/api/v1/watchdog/timeout", 0)  # off again
    c.signed("PUT", "/api/v1/watchdog/tripped", 0)  # a clear (extensions §3: only 0 may be written)
    c.call("GET", "/api/v1/watchdog")
    c.signed("PUT", "/api/v1/inputs/type", 5, expect=404)  # an 8318 resource on the 8350
    c.call("PUT", "/api/v1/do/0/state", raw=b"{" + b" " * 4000 + b"}", expect=413)
    c.call("GET", "/api/v1/di/0?" + "x" * 300, expect=414)
    exercise_settings(c)
    c.signed("DELETE", "/api/v1/session")
    c.signed("DELETE", "/api/v1/session", expect=401)  # ended


def x25519(k, u):
    """RFC 7748 §5 (the page's and the utility's side of a password change)."""
    p = 2**255 - 19
    k = bytearray(k)
    k[0] &= 248
    k[31] = (k[31] & 127) | 64
    n, x1 = int.from_bytes(k, "little"), int.from_bytes(u, "little") & ((1 << 255) - 1)
    x2, z2, x3, z3, swap = 1, 0, x1, 1, 0
    for t in range(254, -1, -1):
        bit = (n >> t) & 1
        if swap ^ bit:
            x2, x3, z2, z3 = x3, x2, z3, z2
        swap = bit
        a, b = (x2 + z2) % p, (x2 - z2) % p
        aa, bb = a * a % p, b * b % p
        e = (aa - bb) % p
        da, cb = (x3 - z3) * a % p, (x3 + z3) * b % p
        x3, z3 = (da + cb) ** 2 % p, x1 * (da - cb) ** 2 % p
        x2, z2 = aa * bb % p, e * (aa + 121665 * e) % p
    if swap:
        x2, z2 = x3, z3
    return (x2 * pow(z2, p - 2, p) % p).to_bytes(32, "little")


def seal(shared, context, data):
    """protocol/src/auth.rs `seal`."""
    key = hmac.new(shared, context, hashlib.sha256).digest()
    out = bytearray(data)
    for block in range((len(out) + 31) // 32):
        stream = hmac.new(key, tag(b"RDAQ seal") + bytes([block]), hashlib.sha256).digest()
        for i in range(32):
            if block * 32 + i < len(out):
                out[block * 32 + i] ^= stream[i]
    return bytes(out)


def sealed_body(module, label, plain):
    """`{module, public, sealed}`: `plain` sealed for the module's offered key under `label`
    with a key pair made here, as a client does (docs/web.md)."""
    secret = os.urandom(32)
    sealed = seal(x25519(secret, module), tag(label) + module, plain)
    public = x25519(secret, (9).to_bytes(32, "little"))
    return json.dumps({"module": module.hex(), "public": public.hex(), "sealed": sealed.hex()}).encode()


def credential(password, iterations=4096):
    """The encoded credential of `password` (protocol/src/auth.rs Credential::encode)."""
    salt = os.urandom(16)
    salted = hashlib.pbkdf2_hmac("sha256", password.encode(), salt, iterations, 32)
    client_key = hmac.new(salted, b"Client Key", hashlib.sha256).digest()
    return (salt + iterations.to_bytes(4, "big") + hashlib.sha256(client_key).digest()
            + hmac.new(salted, b"Server Key", hashlib.sha256).digest())


def change_password(c, new):
    """docs/web.md: the module's key (its proof checked), the credential sealed, stored."""
    c.signed("PUT", "/api/v1/password", raw=sealed_body(module_key(c), b"RDAQ web new credential", credential(new)))


def module_key(c):
    """The module's ephemeral key for a sealed secret (`POST /api/v1/password/key`), its proof
    checked against the session's key."""
    status, offer = c.signed("POST", "/api/v1/password/key", expect=200)
    offer = json.loads(offer)
    module = bytes.fromhex(offer["public"])
    proof = hmac.new(c.session[1], tag(b"RDAQ web agreement") + module, hashlib.sha256).hexdigest()
    if proof != offer["proof"]:
        raise RuntimeError("the module's key is not signed by the session")
    return module


def put_mqtt_credentials(c, user, password, expect=204):
    """docs/openapi.yaml MqttCredentials: the name and password laid out and sealed here, as
    a client does."""
    plain = (bytes([len(user)]) + user.encode().ljust(32, b"\0") + bytes([len(password)])
             + password.encode().ljust(64, b"\0"))
    body = sealed_body(module_key(c), b"RDAQ web mqtt credentials", plain)
    c.signed("PUT", "/api/v1/mqtt/credentials", raw=body, expect=expect)


# A CA certificate (P-256, made once by openssl for these checks, 393 bytes as DER; any will do:
# the module only stores it here), its PEM lines joined by spaces as the API takes them.
CA_PEM = ("-----BEGIN CERTIFICATE----- "
          "MIIBhTCCASugAwIBAgIUBAAIK0QRcGZtAk4TOpwds6gwuEgwCgYIKoZIzj0EAwIw "
          "GDEWMBQGA1UEAwwNcmRhcSBhcGkgdGVzdDAeFw0yNjEyMDUxOTExMzZaFw0zNjEy "
          "MDIxOTExMzZaMBgxFjAUBgNVBAMMDXJkYXEgYXBpIHRlc3QwWTATBgcqhkjOPQIB "
          "BggqhkjOPQMBBwNCAAQGknrPv05okRuxq86Vn+PFlf/OHbUgc2596Wzaeg0WitjX "
          "23V/sQ9le/kD8UgsWMufTcvwaQDXXX4t2ZcZ72FKo1MwUTAdBgNVHQ4EFgQUxu4d "
          "iTmod3WoxOO5eR8N/EWImq0wHwYDVR0jBBgwFoAUxu4diTmod3WoxOO5eR8N/EWI "
          "mq0wDwYDVR0TAQH/BAUwAwEB/zAKBggqhkjOPQQDAgNIADBFAiEA4nCLcAQn48SV "
          "PUwZqSKwHwxx7be/xFLh11tL4bIiAbYCIGyuGLhw9hmypsrEbJ3C64T+8s/5F6RI "
          "2U8BRfaUcGSA "
          "-----END CERTIFICATE-----")


# MQTT settings a test sets (docs/mqtt.md): on, plain, a documentation-only broker address
# (RFC 5737: nothing answers there).
MQTT = {"on": True, "broker": "192.0.2.50", "host": "", "port": 1883, "client_id": "rdaq-api-test", "tls": False,
        "prefix": "plant/line-2", "period_ms": 1000, "qos": 1, "deadbands": [50, 0, 0, 0, 0, 0, 0, 7],
        "on_change": True, "commands": False, "sntp": "192.0.2.1"}


def exercise_settings(c):
    """The network settings, the allow-list, the password and the restart (both modules;
    logged in with the factory password)."""
    c.call("GET", "/api/v1/network")
    net = {"ip": "192.0.2.10", "mask": "255.255.255.0", "gateway": "192.0.2.1", "modbus_port": 8000, "http_port": 8080}
    c.call("PUT", "/api/v1/network", raw=json.dumps(net).encode(), expect=401)  # unsigned
    c.signed("PUT", "/api/v1/network", raw=json.dumps(dict(net, mask="255.0.255.0")).encode(), expect=422)
    c.signed("PUT", "/api/v1/network", raw=json.dumps(dict(net, ip="127.0.0.2")).encode(), expect=422)
    c.signed("PUT", "/api/v1/network", raw=json.dumps(dict(net, http_port=8301)).encode(), expect=422)
    c.signed("PUT", "/api/v1/network", raw=b'{"ip":"192.0.2.10"}', expect=400)
    c.signed("PUT", "/api/v1/network", raw=json.dumps(net).encode())
    c.call("GET", "/api/v1/network")
    c.call("GET", "/api/v1/access", expect=401)  # shown to a session only
    c.signed("GET", "/api/v1/access", expect=200)
    allow = json.dumps({"networks": ["127.0.0.0/8", "192.0.2.7"]}).encode()
    c.signed("PUT", "/api/v1/access", raw=allow, expect=403)  # not with the factory password
    # MQTT's settings (docs/mqtt.md): a session's only; no change with the factory password.
    c.call("GET", "/api/v1/mqtt", expect=401)
    c.signed("GET", "/api/v1/mqtt", expect=200)
    c.signed("PUT", "/api/v1/mqtt", raw=json.dumps(MQTT).encode(), expect=403)
    c.signed("PUT", "/api/v1/mqtt/ca", raw=json.dumps({"pem": CA_PEM}).encode(), expect=403)
    # The password: no key asked for (409), junk, a credential the module does not take (422).
    junk = {"module": "00" * 32, "public": "11" * 32, "sealed": "22" * 84}
    c.signed("PUT", "/api/v1/password", raw=json.dumps(junk).encode(), expect=409)
    c.signed("PUT", "/api/v1/password", raw=b'{"public":"00"}', expect=400)
    module = module_key(c)
    # Sealed for another key than the one offered (an older offer's): refused, the offer kept.
    c.signed("PUT", "/api/v1/password", raw=json.dumps(junk).encode(), expect=409)
    # Sealed right, but 10 PBKDF2 iterations (under auth::MIN_ITERATIONS): refused. Not random
    # bytes here: the seal has no tag, so junk unseals to an acceptable credential (iterations
    # 4096..=10^7) once in about 430 tries, and would set a password nobody knows (a CI run did).
    weak = sealed_body(module, b"RDAQ web new credential", credential("correct horse battery", 10))
    c.signed("PUT", "/api/v1/password", raw=weak, expect=422)
    c.call("PUT", "/api/v1/password", raw=b"{}", expect=401)  # unsigned
    change_password(c, "correct horse battery")
    c.signed("GET", "/api/v1/access", expect=401)  # the session of the old password ended
    if c.log_in("correct horse battery") != 200:
        raise RuntimeError("the new password did not log in")
    c.signed("PUT", "/api/v1/access", raw=json.dumps({"networks": ["10.0.0.0/33"]}).encode(), expect=422)
    five = {"networks": [f"10.{i}.0.0/16" for i in range(5)]}
    c.signed("PUT", "/api/v1/access", raw=json.dumps(five).encode(), expect=422)
    c.signed("PUT", "/api/v1/access", raw=allow)
    c.signed("GET", "/api/v1/access", expect=200)
    c.signed("PUT", "/api/v1/access", raw=json.dumps({"networks": []}).encode())
    for wrong in [dict(MQTT, qos=2), dict(MQTT, deadbands=[0] * 7), dict(MQTT, prefix="plant/#"),
                  dict(MQTT, period_ms=99), dict(MQTT, broker="224.0.0.1")]:
        c.signed("PUT", "/api/v1/mqtt", raw=json.dumps(wrong).encode(), expect=422)
    c.signed("PUT", "/api/v1/mqtt", raw=b'{"on":true}', expect=400)
    c.signed("PUT", "/api/v1/mqtt", raw=json.dumps(MQTT).encode())
    c.signed("PUT", "/api/v1/mqtt", raw=json.dumps(dict(MQTT, on=False)).encode())
    c.signed("PUT", "/api/v1/mqtt/ca", raw=b'{"pem":"not a certificate"}', expect=422)
    c.signed("PUT", "/api/v1/mqtt/ca", raw=b'{"der":"30"}', expect=400)
    c.signed("PUT", "/api/v1/mqtt/ca", raw=json.dumps({"pem": CA_PEM}).encode())
    junk = {"module": "00" * 32, "public": "11" * 32, "sealed": "22" * 98}
    c.signed("PUT", "/api/v1/mqtt/credentials", raw=json.dumps(junk).encode(), expect=409)
    put_mqtt_credentials(c, "plant-daq", "broker password")
    shown = json.loads(c.signed("GET", "/api/v1/mqtt", expect=200)[1])
    if not (shown.get("ca") and shown.get("credentials")) or "broker password" in json.dumps(shown):
        raise RuntimeError(f"the CA and credentials stored, never shown: {shown}")
    put_mqtt_credentials(c, "", "")
    c.signed("PUT", "/api/v1/mqtt/ca", raw=b'{"pem":""}')
    exercise_firmware(c)
    c.call("POST", "/api/v1/restart", expect=401)


def exercise_firmware(c):
    """The firmware upload's refusals: on the host build, which has no update partition, 503;
    an image of the QEMU board refuses the header (the whole upload: tools/browser under QEMU)."""
    c.call("GET", "/api/v1/firmware")
    header = bytes(146)
    c.call("POST", "/api/v1/firmware", raw=header, expect=401)  # unsigned
    c.signed("POST", "/api/v1/firmware", raw=header[:10], expect=400)
    c.signed("POST", "/api/v1/firmware", raw=header, expect=422 if c.updates else 503)
    c.signed("PUT", "/api/v1/firmware/0", raw=b"\xff" * 512, expect=409)  # no upload
    c.signed("PUT", "/api/v1/firmware/0", raw=b"\xff" * 513, expect=400)
    c.signed("POST", "/api/v1/firmware/finish", expect=409)


def exercise_8318(c):
    c.call("GET", "/api/v1/identity")
    if c.log_in(FACTORY_PASSWORD) != 200:
        raise RuntimeError("the factory password did not log in")
    for target, status in [("/api/v1/channels", 200), ("/api/v1/channels/0", 200), ("/api/v1/channels/3", 200),
                           ("/api/v1/channels/8", 404), ("/api/v1/inputs", 200), ("/api/v1/diagnostics", 200),
                           ("/api/v1/di", 404), ("/api/v1/watchdog", 404)]:
        c.call("GET", target, expect=status)
    c.signed("PUT", "/api/v1/inputs/type", 5)
    c.call("GET", "/api/v1/channels")
    c.call("GET", "/api/v1/inputs")
    c.signed("PUT", "/api/v1/inputs/type", 99, expect=422)  # no such type (spec §2.2)
    c.signed("PUT", "/api/v1/inputs/cjc_offset", 1.25)
    c.signed("PUT", "/api/v1/inputs/cjc_offset", 1.255, expect=422)  # hundredths of °C at most
    c.signed("PUT", "/api/v1/inputs/open_value", "downscale")
    c.signed("PUT", "/api/v1/inputs/enable_mask", 0x0F)
    c.call("GET", "/api/v1/channels/5")  # disabled
    c.signed("PUT", "/api/v1/inputs/cjc", 30, expect=405)  # read-only
    exercise_settings(c)
    # Last: the module restarts (stopped after this by the checker).
    c.signed("POST", "/api/v1/restart", expect=202)


def main():
    """`check_api.py [TARGET_DIR]`: the host build of both models (default target/debug);
    `check_api.py --qemu IMAGES_DIR`: both models' images of the QEMU board (the features the
    STM32 images ship with: the web console, the update service)."""
    qemu = len(sys.argv) > 2 and sys.argv[1] == "--qemu"
    target = sys.argv[2] if qemu else (sys.argv[1] if len(sys.argv) > 1 else "target/debug")
    with open(SPEC) as f:
        spec = yaml.safe_load(f)
    api = Api(spec)
    work = tempfile.mkdtemp(prefix="rdaq-openapi-")
    modules, failed_setup = [], 0
    try:
        if qemu:
            # The QEMU board's DI0 is a 1 kHz square wave (boards/qemu/src/digital.rs).
            m8350 = QemuModule(os.path.join(target, "firmware-8350"), log=os.path.join(work, "firmware-8350.qemu.log"))
            modules.append(m8350)
            m8318 = QemuModule(os.path.join(target, "firmware-8318"), log=os.path.join(work, "firmware-8318.qemu.log"))
        else:
            m8350 = Module(os.path.join(target, "firmware-8350"), work, "[di0]\nsquare_hz = 5.0\n")
            modules.append(m8350)
            m8318 = Module(os.path.join(target, "firmware-8318"), work,
                           "cjc_celsius = 25.0\n[ch0]\nmillivolts = 41.276\n[ch3]\nopen = true\n")
        modules.append(m8318)
        exercise_8350(Client(api, m8350))
        exercise_8318(Client(api, m8318))
    except Exception as e:
        failed_setup = 1
        print(f"openapi requests ... FAILED: {e}", flush=True)
    finally:
        for m in modules:
            m.stop()
    passed, failed, not_applicable = 0, failed_setup, 0
    for template, item in spec["paths"].items():
        for method in [m for m in item if m in ("get", "put", "post", "delete")]:
            problems = api.seen.pop((method.upper(), template), None)
            name = f"{method.upper()} {template}"
            if problems is None:
                failed += 1
                print(f"openapi {name} ... FAILED: never exercised", flush=True)
            elif problems:
                failed += 1
                print(f"openapi {name} ... FAILED: {'; '.join(problems)}", flush=True)
            else:
                passed += 1
                print(f"openapi {name} ... ok", flush=True)
    for (method, path), problems in api.seen.items():
        failed += 1
        print(f"openapi {method} {path} ... FAILED: {'; '.join(problems) or 'not in the file'}", flush=True)
    print(f"openapi: {passed} passed, {failed} failed" + (f", {not_applicable} not applicable" if not_applicable else ""))
    return 0 if failed == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
