#!/usr/bin/env python3
"""The web console's part of an STM32 image (issue #39, docs/web.md "Budgets").

Usage: web_part.py LABEL WITH_ELF WITHOUT_ELF

The part is the difference between the image built with the console (the default) and the same
image built without it (`--no-default-features --features board-stm32`), as scripts/size-report
counts an image: flash = .vector_table + .text + .rodata + .data + .ccmdata; RAM = .data + .bss +
.uninit (SRAM) + .ccmdata + .ccmbss + .ccmram (CCM).

Then what each piece of it takes, in the image with the console:
- code, by the source file each instruction came from (the DWARF line table, which names the
  innermost inlined function's file, read with binutils' readelf): the server (picoserve, and
  our connection tasks: services/web/src/service/connection.rs, services/web/src/embassy.rs),
  the router (services/web/src/service/router.rs), the API (the rest of services/web/src,
  protocol/src/web.rs, and what of shared only the API uses in these images: json.rs,
  points.rs, modbus/request.rs);
- the pages: each gzip member found in .rodata (the console's files as served), its length
  read by decompressing it;
- other code: what .text grew by beyond those (library code inlined into the console's, the
  update task's side of the upload); strings and tables: what .rodata grew by beyond the pages;
  initial values: .data and .ccmdata's growth.
RAM: the connection tasks' pool (the static named `web::POOL`), and the rest.

Prints one line per piece, then `web-part: LABEL FLASH RAM` for scripts/size-report's checks.
"""

import re
import subprocess
import sys
import zlib

FLASH = (".vector_table", ".text", ".rodata", ".data", ".ccmdata")
RAM = (".data", ".bss", ".uninit", ".ccmdata", ".ccmbss", ".ccmram")


def sections(elf):
    """{name: (size, file offset, address)} of the ELF's sections (readelf -S -W)."""
    out = subprocess.run(["readelf", "-S", "-W", elf], capture_output=True, text=True, check=True).stdout
    found = {}
    for line in out.splitlines():
        m = re.match(r"\s*\[\s*\d+\]\s+(\S+)\s+\S+\s+([0-9a-f]+)\s+([0-9a-f]+)\s+([0-9a-f]+)", line)
        if m:
            found[m.group(1)] = (int(m.group(4), 16), int(m.group(3), 16), int(m.group(2), 16))
    return found


def totals(elf):
    s = sections(elf)
    return (sum(s.get(n, (0,))[0] for n in FLASH), sum(s.get(n, (0,))[0] for n in RAM))


def code_by_file(elf):
    """Bytes of code per source file: each line-table row's address up to the next row's."""
    out = subprocess.run(
        ["readelf", "--debug-dump=decodedline", elf], capture_output=True, text=True, check=True
    ).stdout
    current, rows = None, []
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 1 and parts[0].endswith(":"):
            current = parts[0][:-1]
        elif len(parts) >= 3 and parts[2].startswith("0x"):
            rows.append((int(parts[2], 16), current))
    rows.sort()
    by_file = {}
    for (at, path), (following, _) in zip(rows, rows[1:]):
        # A row's code runs to the next row's address; a gap of a page or more is the end of a
        # sequence (another function's rows follow elsewhere), not code.
        if 0 < following - at < 4096 and path:
            by_file[path] = by_file.get(path, 0) + following - at
    return by_file


def piece_of(path):
    if re.search(r"/picoserve-[0-9][^/]*/", path):
        return "server"
    if path.endswith(("services/web/src/service/connection.rs", "services/web/src/embassy.rs")):
        return "server"
    if path.endswith("services/web/src/service/router.rs"):
        return "router"
    # The API's readers and writers that live in shared for another service's sake (MQTT's too):
    # the flat JSON reader, the points' formatter, the write requests.
    if "services/web/src/" in path or path.endswith(
        ("protocol/src/web.rs", "shared/src/json.rs", "shared/src/points.rs", "shared/src/modbus/request.rs")
    ):
        return "api"
    return None


def pages(elf):
    """The gzip members in .rodata: (count, bytes)."""
    size, offset, _ = sections(elf)[".rodata"]
    with open(elf, "rb") as f:
        f.seek(offset)
        data = f.read(size)
    count, total, at = 0, 0, 0
    while True:
        at = data.find(b"\x1f\x8b\x08", at)
        if at < 0:
            return count, total
        d = zlib.decompressobj(wbits=31)
        try:
            d.decompress(data[at:])
        except zlib.error:
            at += 1
            continue
        if not d.eof:
            at += 1
            continue
        length = len(data) - at - len(d.unused_data)
        count, total, at = count + 1, total + length, at + length


def pool(elf, task="web"):
    """Bytes of an image task's pool (`web`: the connection tasks'; its mangled name holds
    `3web4POOL`, the length of the task's name before it)."""
    out = subprocess.run(["nm", "-S", elf], capture_output=True, text=True, check=True).stdout
    name = f"{len(task)}{task}4POOL"
    return sum(int(p[1], 16) for p in (line.split() for line in out.splitlines()) if len(p) == 4 and name in p[3])


def main():
    label, with_web, without = sys.argv[1:4]
    (f1, r1), (f0, r0) = totals(with_web), totals(without)
    flash, ram = f1 - f0, r1 - r0
    code = {"server": 0, "router": 0, "api": 0}
    for path, n in code_by_file(with_web).items():
        piece = piece_of(path)
        if piece:
            code[piece] += n
    count, gz = pages(with_web)
    s1, s0 = sections(with_web), sections(without)
    grown = {n: s1.get(n, (0,))[0] - s0.get(n, (0,))[0] for n in FLASH}
    other_code = grown[".text"] - sum(code.values())
    tables = grown[".rodata"] - gz
    rest = flash - sum(code.values()) - gz - other_code - tables
    tasks = pool(with_web)
    print(f"web part of {label}: flash {flash} B, RAM {ram} B (the image with the console less the image without)")
    print(f"  flash: server (picoserve, connection tasks) {code['server']} B; router {code['router']} B; "
          f"API {code['api']} B; pages ({count} gzip files) {gz} B; other code the console brings "
          f"(library and shared code, the update task's side of the upload) {other_code} B; strings and tables "
          f"{tables} B; initial values {rest} B")
    print(f"  RAM: the connection tasks' pool {tasks} B; the rest {ram - tasks} B")
    if count == 0:
        print("  (no gzip file found in .rodata: the pages are missing)")
    print(f"web-part: {label} {flash} {ram} {count}")


if __name__ == "__main__":
    main()
