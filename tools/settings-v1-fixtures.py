"""Makes the settings-v1 fixtures of firmware-8318/tests and firmware-8350/tests: runs the host
builds of an older firmware (settings version 1, e.g. 6e1ce2c) with blank flash images, writes
settings over Modbus, and leaves the flash images.

    git worktree add /tmp/old 6e1ce2c && (cd /tmp/old && cargo build -p firmware-8318 -p firmware-8350)
    python3 tools/settings-v1-fixtures.py /tmp/old/target/debug OUT_DIR
"""
import socket, struct, subprocess, time, sys
def run(binary, flash, writes, port):
    p = subprocess.Popen([binary, "--listen", f"127.0.0.1:{port}", "--discovery", f"127.0.0.1:{port+300}", "--flash", flash],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    for _ in range(100):
        try:
            s = socket.create_connection(("127.0.0.1", port), timeout=2); break
        except OSError:
            time.sleep(0.1)
    tid = 1
    for addr, values in writes:
        pdu = struct.pack(">BHHB", 0x10, addr, len(values), 2*len(values)) + b"".join(struct.pack(">H", v) for v in values)
        s.sendall(struct.pack(">HHHB", tid, 0, len(pdu)+1, 1) + pdu)
        ans = s.recv(256)
        assert ans[7] == 0x10, (hex(addr), ans.hex())
        tid += 1
    s.close(); time.sleep(0.3); p.kill(); p.wait()
old, out = sys.argv[1] + "/", sys.argv[2] + "/"
# 8350: DI modes 1,2,3,4,0,1,... ; DO modes 1,0,1,0,0,1; DO0 low 7 high 9 count 11; DO5 low 3 high 4 count 0;
# watchdog 2.5 s (25), mode 1, safe 0b000101, power-on 0b101000
run(old+"firmware-8350", out + "8350-v1.img", [
    (0x100, [1,2,3,4,0,1,2,3,4,0,1,2]),
    (0x110, [1,0,1,0,0,1]),
    (0x18, [7,0]), (0x24, [9,0]), (0x30, [11,0]),
    (0x18+10, [3,0]), (0x24+10, [4,0]), (0x30+10, [0,0]),
    (0x130, [25]), (0x132, [1]), (0x131, [0b000101]), (0x134, [0b101000]),
], 18502)
# 8318: type K (0x0F), CJC offset -2.50 °C (FF06h), enable mask 0x5A
run(old+"firmware-8318", out + "8318-v1.img", [(0xC8, [0x0F]), (0xD7, [0xFF06]), (0xDC, [0x5A])], 18503)
print("ok")
