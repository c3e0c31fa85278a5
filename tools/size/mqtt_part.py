#!/usr/bin/env python3
"""MQTT's part of an STM32 image (issue #40, docs/mqtt.md "Sizes").

Usage: mqtt_part.py LABEL WITH_ELF WITHOUT_ELF

The part is the difference between the image as shipped (feature `mqtt-tls`, the default: MQTT
over TLS) and the same image built without MQTT (`--no-default-features --features
board-stm32,web`), counted as
scripts/size-report counts an image (web_part.py's `totals`). Then what each piece adds: code by
the source file each instruction came from (web_part.py's `code_by_file`), in the image with
MQTT less the same files' in the image without: the client (minimq), TLS (embedded-tls, its
cryptography, our certificate check and record guards), the service (services/mqtt/src, the settings' record
in shared/src/mqtt.rs); RAM: the MQTT task's pool (the static named `mqtt::POOL`: its socket
and session buffers), and the rest (the stack's socket for it).

Prints one line per piece, then `mqtt-part: LABEL FLASH RAM SERVICE_CODE` for
scripts/size-report.

Usage: mqtt_part.py --tls LABEL WITH_TLS_ELF WITHOUT_TLS_ELF

TLS's part of an STM32 image (docs/mqtt.md "Sizes"): the image as shipped (feature `mqtt-tls`)
less the same image built with MQTT in plain TCP only (`--no-default-features --features
board-stm32,web,mqtt`); the code of embedded-tls, its
cryptography and our certificate check and record guards; the RAM TLS adds to MQTT's task pool
(`mqtt::POOL`, on the background executor: the record buffers, the whole-record buffer, the
connection and the handshake's state), the rest. Prints the lines only.
"""

import re
import sys

from web_part import code_by_file, pool, totals

TLS_CRATES = ("embedded-tls", "p256", "elliptic-curve", "primeorder", "aes-gcm", "aes", "ghash", "sha2",
              "hkdf", "hmac", "der", "x509", "rustpki", "signature", "ecdsa")


def piece_of(path):
    if re.search(r"/minimq-[0-9][^/]*/", path):
        return "client"
    if any(re.search(rf"/{c}-[0-9][^/]*/", path) for c in TLS_CRATES) or path.endswith(
            ("services/mqtt/src/tls.rs", "services/mqtt/src/certificate.rs", "services/mqtt/src/records.rs")):
        return "tls"
    if "services/mqtt/src/" in path or path.endswith("shared/src/mqtt.rs"):
        return "service"
    return None


def tls_part(label, with_tls, without):
    (f1, r1), (f0, r0) = totals(with_tls), totals(without)
    flash, ram = f1 - f0, r1 - r0
    code = 0
    for elf, sign in ((with_tls, 1), (without, -1)):
        code += sign * sum(n for path, n in code_by_file(elf).items() if piece_of(path) == "tls")
    in_pool = pool(with_tls, "mqtt") - pool(without, "mqtt")
    print(f"TLS part of {label}: flash {flash} B, RAM {ram} B (the image with MQTT over TLS less the image with plain MQTT only)")
    print(f"  code: embedded-tls, its cryptography and the certificate check {code} B; the rest of the flash {flash - code} B")
    print(f"  RAM: in MQTT's task pool {in_pool} B (record buffers, whole records, the connection); the rest {ram - in_pool} B; "
          f"its stack is MQTT's task's, on the background executor, on the main stack on the STM32 "
          f"(12.3 KB under QEMU, docs/mqtt.md)")


def main():
    if sys.argv[1] == "--tls":
        tls_part(*sys.argv[2:5])
        return
    label, with_mqtt, without = sys.argv[1:4]
    (f1, r1), (f0, r0) = totals(with_mqtt), totals(without)
    flash, ram = f1 - f0, r1 - r0
    # Each piece's code in the image with MQTT less the same files' in the image without (the
    # cryptography TLS shares with the other services is in both).
    code = {"client": 0, "tls": 0, "service": 0}
    for elf, sign in ((with_mqtt, 1), (without, -1)):
        for path, n in code_by_file(elf).items():
            piece = piece_of(path)
            if piece:
                code[piece] += sign * n
    tasks = pool(with_mqtt, "mqtt")
    print(f"MQTT part of {label}: flash {flash} B, RAM {ram} B (the image with MQTT less the image without)")
    print(f"  code: client (minimq) {code['client']} B; TLS {code['tls']} B; the service (services/mqtt, "
          f"its settings' record) {code['service']} B; the rest of the flash (library code inlined, strings, "
          f"the web console's MQTT resource) {flash - sum(code.values())} B")
    print(f"  RAM: the MQTT task's pool {tasks} B (socket and session buffers); the rest {ram - tasks} B")
    print(f"mqtt-part: {label} {flash} {ram} {code['service']}")


if __name__ == "__main__":
    main()
