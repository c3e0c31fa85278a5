#!/usr/bin/env python3
"""Issue #38's findings (the second security review, ../shared/reviews/security-4cfaadc.md) as
attacks, with real packets on loopback against the simulated modules of one version of this
repository.

    issue38.py BIN_DIR [--label NAME] [--only ATTACK]...

The same harness, outcomes and output as attacks.py (issue #20's): `attacks: N expected`, one
line per attack (`succeeded`, `failed`: refused and shown so, `error`: neither shown), then the
summary line. scripts/attacks runs them against this tree (each must fail) and, with
`--set 38 --against 4cfaadc`, against the reviewed commit (each must succeed there).

The findings shown elsewhere, as tests of this tree only: 3 and 15 (the utility:
`utility/src/worker.rs`, `utility/src/trend.rs`), 10 and 11c (the bootloaders:
`services/update/tests/`), 6 (keyed ISNs: scripts/isn-predict, under QEMU), 12 (broadcast answers: `services/discovery/tests/discovery.rs`).
"""

import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import attacks as base  # noqa: E402
from attacks import FACTORY, OWN, Sim, allow_only_the_master, need, set_own_password, verdict  # noqa: E402
from rdaq import Modbus, command, net_body  # noqa: E402

ATTACKS = []


def attack(name):
    """Registers an attack of this file."""
    return base.attack(name, ATTACKS)


# docs/security.md, "Flash wear": authenticated changes draw on a burst of 20 commits, then one
# more every 15 minutes; a refusal answers status 9 and is counted in register 40256.
ADMIN_BURST = 20
COMMIT_BUDGET = 9


@attack("flash-wear-under-the-factory-password")
def flash_wear_factory():
    """Finding 1: on an unclaimed module, anyone proves the public factory password and commits
    network settings as fast as the round trip allows, alternating two so that each is a change;
    then restarts the module (which the factory password also allows) and goes on."""
    tries = 60
    with Sim(8350) as sim:
        ports = (8001, 8002)

        def set_the_other_port():
            """SET_NETWORK of the port not in force (each one a change to commit): its status,
            and whether the stored port changed."""
            before = sim.stored()["port"]
            port = ports[0] if before == ports[1] else ports[1]
            status = command(sim, 0x02, net_body([192, 168, 0, 1], [255, 255, 255, 0], [0, 0, 0, 0], port), FACTORY)
            return status, sim.stored()["port"] == port

        answers = [set_the_other_port() for _ in range(tries)]
        need(answers[0] == (0, True), f"the first SET_NETWORK under the factory password was not stored: {answers[0]}")
        committed = sum(1 for status, changed in answers if status == 0 and changed)
        refused = [status for status, changed in answers[ADMIN_BURST:] if not changed]
        stored = sim.stored()
        m = Modbus(sim.modbus)
        counted = m.read(0xFF)
        m.close()
        # The restart: anyone may, with the factory password.
        need(command(sim, 0x03, b"", FACTORY) == 0, "RESTART under the factory password was refused")
        time.sleep(1.0)
        uptime = sim.uptime_at_least(0, 20)
        need(uptime <= 3, f"the module did not restart (uptime {uptime} s)")
        more = [set_the_other_port() for _ in range(5)]
        after = sim.stored()
        seen = (f"{tries} SET_NETWORK of the other port under the factory password: {committed} stored"
                f", {len(refused)} refused with {sorted(set(refused))}; register 40256: {counted}; restarted (uptime"
                f" {uptime} s), then 5 more: {sum(1 for _, c in more if c)} stored, answers {[s for s, _ in more]}")
        return verdict(committed == tries and all(c for _, c in more),
                       committed == ADMIN_BURST and refused == [COMMIT_BUDGET] * (tries - ADMIN_BURST)
                       and counted == [tries - ADMIN_BURST] and more == [(COMMIT_BUDGET, False)] * 5
                       and after == stored, seen)


MASTER, OUTSIDER = "127.0.0.2", "127.0.0.3"


@attack("an-outsider-clears-the-masters-latch")
def outsider_clears_latch():
    """Finding 2: while an allow-list admits only the master, a client outside it reads the DI
    latch flags, which are cleared when read, so the master never sees its event."""
    scenario = os.path.join(base.TMP, "di0-from-do0.toml")
    with open(scenario, "w") as f:
        f.write("[di0]\nfrom_do = 0\n")
    with Sim(8350, scenario) as sim:
        allow_only_the_master(sim)
        master, outsider = Modbus(sim.modbus, MASTER), Modbus(sim.modbus, OUTSIDER)
        try:
            need(outsider.write(0x100, 2) is not True, "the allow-list is not in force: the outsider wrote")
            need(master.write(0x100, 2) is True, "the master could not set DI0 to a low-to-high latch")
            need(master.write_coil(0x10, False) is True, "DO0 off")
            time.sleep(0.3)
            master.coils(0x23, 1)  # clears any latch from before
            # The event: DO0, wired to DI0, goes high.
            need(master.write_coil(0x10, True) is True, "DO0 on")
            time.sleep(0.3)
            need(master.coils(0x00, 1) == [1], "DI0 did not follow DO0 (the scenario's wiring)")
            seen_by_outsider = [outsider.coils(0x23, 1) for _ in range(3)]
            seen_by_master = master.coils(0x23, 1)
            again = master.coils(0x23, 1)
        finally:
            master.close()
            outsider.close()
        need([1] in seen_by_outsider, f"the outsider never saw the latch: {seen_by_outsider}")
        seen = (f"DI0 latched (DO0 wired to it went high); the outsider's 3 reads of latch 0023h: {seen_by_outsider}; "
                f"then the master's read: {seen_by_master}, and its next: {again}")
        return verdict(seen_by_master == [0], seen_by_master == [1] and again == [0], seen)


@attack("a-damaged-store-unclaims-the-module")
def damaged_store():
    """Finding 9: a claimed module whose settings store can no longer be read (here: its flash
    image overwritten, as a worn or disturbed flash might leave it) loads factory defaults, the
    factory password included, so anyone on the LAN can then claim it."""
    with Sim(8350) as sim:
        set_own_password(sim, OWN)
        need(command(sim, 0x06, b"", FACTORY) == 1, "the factory password still works after the password was set")
        flash = sim.flash
    with open(flash, "r+b") as f:
        size = len(f.read())
        f.seek(0)
        f.write(bytes([0x55]) * size)
    with Sim(8350, flash=flash) as sim:
        factory = command(sim, 0x06, b"", FACTORY)
        own = command(sim, 0x06, b"", OWN)
        m = Modbus(sim.modbus)
        served = m.read(0xD2)
        m.close()
        need(served is not None, "the module on the damaged store does not serve Modbus")
        seen = (f"the claimed module's store ({size} B) overwritten; at the next start GET_ACCESS with the factory "
                f"password: status {factory}, with the administrator's: {own}; a Modbus read served")
        return verdict(factory == 0, factory == 1 and own == 1, seen)


if __name__ == "__main__":
    base.main(ATTACKS, __doc__)
