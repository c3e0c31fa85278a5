"""A QEMU image of the module on a TAP device in a network namespace of its own, for the attacks
under QEMU (junk_flood.py, isn_predict.py): the namespace, the TAP device with this side's
addresses, and QEMU booting the image through its bootloader (as tools/qemu-e2e boots it). The
module is the QEMU board's fixed 10.0.2.15 there."""

import os
import struct
import subprocess

MODULE = "10.0.2.15"


def sh(*args, check=True):
    return subprocess.run(list(args), check=check, capture_output=True, text=True)


def in_ns(ns, *args):
    return ["ip", "netns", "exec", ns, *args]


def start(image, ns, tap, addresses, log):
    """The namespace `ns` with `tap` up at each of `addresses` (a.b.c.d, /24), and QEMU running
    `image` (IMAGE.bin, its bootloader beside it) on `tap`, its output to the file `log`: the
    QEMU process."""
    sh("ip", "netns", "add", ns)
    sh(*in_ns(ns, "ip", "link", "set", "lo", "up"))
    sh(*in_ns(ns, "ip", "tuntap", "add", "dev", tap, "mode", "tap"))
    for address in addresses:
        sh(*in_ns(ns, "ip", "addr", "add", f"{address}/24", "dev", tap))
    sh(*in_ns(ns, "ip", "link", "set", tap, "up"))
    bootloader = os.path.join(os.path.dirname(image), "remodaq-qemu-bootloader")
    out = open(log, "w")
    return subprocess.Popen(in_ns(
        ns, "qemu-system-arm", "-M", "mps2-an386", "-nographic", "-monitor", "none", "-serial", "null",
        "-semihosting-config", "enable=on,target=native",
        "-nic", f"tap,model=lan9118,ifname={tap},script=no,downscript=no",
        "-kernel", bootloader, "-device", f"loader,file={image}.bin,addr=0x300000"), stdout=out, stderr=out)


def stop(qemu, ns):
    """QEMU ended and the namespace removed (with its TAP device)."""
    if qemu:
        qemu.kill()
        qemu.wait()
    sh("ip", "netns", "del", ns, check=False)


def checksum(data):
    """The RFC 1071 checksum of `data` (an IPv4 header, or a TCP segment with its pseudo-header)."""
    if len(data) % 2:
        data += b"\0"
    s = sum(struct.unpack(f"!{len(data) // 2}H", data))
    while s >> 16:
        s = (s & 0xFFFF) + (s >> 16)
    return (~s) & 0xFFFF
