"""Instructions and estimated cycles per observer step on an emulated Cortex-M0+ (fixed point) and
Cortex-M4F (float), with the step's flash and RAM, per path of the step.

    python benchmarks/bench_mcu.py [PRESET ...]     (needs arm-none-eabi-gcc and `pip install .[bench]`)

For each preset the generated C (``codegen --precision fixed`` for the M0+, ``--precision float``
for the M4F) is linked bare-metal with a harness that steps the observer on 80 recorded closed-loop
samples; unicorn (a QEMU-based instruction-set emulator) runs the Thumb code and counts the
instructions between two markers around each step call (the call, the step and everything it calls:
libgcc's 64-bit multiply, newlib's libm). Three paths, each printed as its mean and its most cycles:
"accepted", the first 48 samples (plausible ones); "glitch", 16 samples scaled x 50, which the guard
rejects (the coasting branch runs); "at bound", the first 16 plausible samples again, the observer set to
the run's state before them but with its speed state(s) at their bound (the state field the gain
schedule reads, else the last bounded one in rad/s, and every field with the same bound; the sign of
the run's speed) and its angle estimates 0.5 rad behind, so that the samples push the speed beyond
its bound: what happens then is the family's step's choice (the flux observer clamps its PLL speed:
docs/families/pmsm_flux_observer.md). A "where" line under each M0+ row splits the accepted steps'
cycles by function of the image (the step, each helper it calls, libgcc's routines; a helper the
compiler inlined counts as the step). "PRESET+table" runs the preset with the 4-breakpoint gain table
of tests/common/test_fixed_point.py (a tuned table's layout, `codegen --gains TABLE`). Cycles are
estimated per instruction from the cores'
published timings (Cortex-M0+ TRM / Cortex-M4 TRM, table "Instruction timings"): M0+ (single-cycle
multiplier) 1 cycle, loads/stores 2, taken branches 2 (BL 3), PUSH/POP/LDM/STM 1 + N (POP with PC
3 + N); M4F 1 cycle, loads/stores 2, taken branches 2 (BL 3; pipelining is ignored: an upper
estimate), VDIV/VSQRT 14, SDIV/UDIV 7. Flash: the observer object's text + data; RAM: the observer
struct + the step's stack frame (-fstack-usage) + its callees' (not counted: below 100 B here).
"""

from __future__ import annotations

import re
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

FLASH, RAM = 0x0, 0x20000000
N_CLEAN, N_GLITCH, N_BOUND = 48, 16, 16  # closed-loop samples; the same x 50; plausible ones at the bound
N_STEPS = N_CLEAN + N_GLITCH + N_BOUND
BEHIND = 0.5  # rad: the "at bound" path's angle estimates behind the run's, so the speed is pushed out
PATHS = {
    "accepted": (0, N_CLEAN),
    "glitch": (N_CLEAN, N_CLEAN + N_GLITCH),
    "at bound": (N_CLEAN + N_GLITCH, N_STEPS),
}

HARNESS = """#include "%(P)s.h"
extern const %(P)s_input bench_in[%(N)d];
__attribute__((noinline)) void mark_begin(void) { __asm__ volatile(""); }
__attribute__((noinline)) void mark_end(void) { __asm__ volatile(""); }
%(P)s_observer bench_obs;
%(P)s_output bench_out;
void bench_main(void)
{
    int k;
    %(init)s;
    for (k = 0; k < %(N)d; ++k) {
        if (k == %(N_at)d) {
            %(init)s;
%(at_bound)s
        }
        mark_begin();
        %(P)s_step(&bench_obs, &bench_in[k], &bench_out);
        mark_end();
    }
    for (;;) {
    }
}
__attribute__((naked, section(".start"))) void _start(void)
{
    __asm__ volatile("ldr r0, =0x20010000\\n mov sp, r0\\n bl bench_main\\n");
}
"""
LINK = """MEMORY { FLASH (rx) : ORIGIN = 0x0, LENGTH = 1M  RAM (rwx) : ORIGIN = 0x20000000, LENGTH = 64K }
SECTIONS {
  .text : { *(.start) *(.text*) *(.rodata*) } > FLASH
  .data : { *(.data*) } > RAM AT > FLASH
  .bss : { *(.bss*) *(COMMON) } > RAM
  /DISCARD/ : { *(.ARM.exidx*) }
}
"""


def _cycles_m0(ins: str, taken: bool) -> int:
    op = ins.split()[0].lower() if ins else ""
    if op.startswith(("push", "pop", "ldm", "stm")):
        n = ins.count(",") + 1
        return 1 + n + (2 if "pc" in ins and op.startswith("pop") else 0)
    if op.startswith(("ldr", "str")):
        return 2
    if op == "bl":
        return 3
    if op.startswith("b") and taken:
        return 2
    return 1


def _cycles_m4(ins: str, taken: bool) -> int:
    op = ins.split()[0].lower() if ins else ""
    if op.startswith(("vdiv", "vsqrt")):
        return 14
    if op.startswith(("sdiv", "udiv")):
        return 7
    if op.startswith(("push", "pop", "ldm", "stm", "vpush", "vpop", "vldm", "vstm")):
        return 1 + ins.count(",") + 1
    if op.startswith(("ldr", "str", "vldr", "vstr")):
        return 2
    if op == "bl":
        return 3
    if op.startswith("b") and taken:
        return 2
    return 1


def build(
    work: Path, P: str, files: dict[str, str], samples: str, init: str, at_bound: str, cpu: list[str]
) -> Path:
    for name, text in files.items():
        (work / name).write_text(text)
    at = {"P": P, "N": N_STEPS, "N_at": PATHS["at bound"][0], "init": init, "at_bound": at_bound}
    (work / "harness.c").write_text(HARNESS % at)
    (work / "samples.c").write_text(samples)
    (work / "link.ld").write_text(LINK)
    flags = [*cpu, "-mthumb", "-Os", "-std=c99", "-ffreestanding", "-fstack-usage"]
    elf = work / "bench.elf"
    r = subprocess.run(
        [
            "arm-none-eabi-gcc",
            *flags,
            "-nostartfiles",
            "-T",
            str(work / "link.ld"),
            "--specs=nosys.specs",
            "-o",
            str(elf),
            str(work / "harness.c"),
            str(work / f"{P}.c"),
            str(work / "samples.c"),
            "-lm",
            "-lgcc",
        ],
        check=False,
        cwd=work,
        capture_output=True,
        text=True,
    )
    if not elf.exists():
        raise SystemExit(f"link failed: {r.stderr[-2000:]}")
    return elf


def emulate(elf: Path, model: str, where: dict[str, int] | None = None) -> tuple[list[int], list[int]]:
    """(instructions, estimated cycles) of each of the harness's steps; ``where`` (if given) gets the
    cycles of the accepted path's steps per function of the image (the step, each helper it calls
    without inlining, libgcc's routines), for the "where" line."""
    import unicorn
    from unicorn import arm_const as A

    syms = {}
    for line in subprocess.run(
        ["arm-none-eabi-nm", str(elf)], capture_output=True, text=True
    ).stdout.splitlines():
        parts = line.split()
        if len(parts) == 3:
            syms[parts[2]] = int(parts[0], 16)
    binf = elf.with_suffix(".bin")
    subprocess.run(["arm-none-eabi-objcopy", "-O", "binary", "-j", ".text", str(elf), str(binf)], check=True)
    dis = {}
    for line in subprocess.run(
        ["arm-none-eabi-objdump", "-d", str(elf)], capture_output=True, text=True
    ).stdout.splitlines():
        m = re.match(r"\s*([0-9a-f]+):\s+(?:[0-9a-f]{4} ?){1,2}\s+(.*)", line)
        if m:
            dis[int(m.group(1), 16)] = m.group(2).strip()
    uc = unicorn.Uc(unicorn.UC_ARCH_ARM, unicorn.UC_MODE_THUMB | unicorn.UC_MODE_MCLASS)
    uc.ctl_set_cpu_model(getattr(A, f"UC_CPU_ARM_CORTEX_{model}"))
    uc.mem_map(FLASH, 1 << 20)
    uc.mem_map(RAM, 1 << 16)
    uc.mem_write(FLASH, binf.read_bytes())
    data = subprocess.run(
        ["arm-none-eabi-objcopy", "-O", "binary", "-j", ".data", str(elf), "/dev/stdout"], capture_output=True
    ).stdout
    if data:
        uc.mem_write(syms.get("__data_start__", RAM), data)  # .data is empty here (const tables in flash)
    begin, end = syms["mark_begin"], syms["mark_end"]
    starts = sorted((a & ~1, n) for n, a in syms.items() if a < RAM)
    owner: dict[int, str] = {}

    def function_of(address: int) -> str:
        if address not in owner:
            k = max((j for j, (a, _) in enumerate(starts) if a <= address), default=0)
            owner[address] = starts[k][1] if starts else "?"
        return owner[address]

    count = {"on": False, "ins": 0, "cyc": 0, "prev": None, "i0": 0, "c0": 0}
    ins_steps: list[int] = []
    cyc_steps: list[int] = []
    cyc = _cycles_m0 if model == "M0" else _cycles_m4

    def hook(uc, address, size, _):
        prev = count["prev"]
        if count["on"] and prev is not None:
            pa, ps, pins = prev
            taken = address != pa + ps
            c = cyc(pins, taken)
            count["cyc"] += c
            count["ins"] += 1
            if where is not None and len(cyc_steps) < N_CLEAN:
                f = function_of(pa)
                where[f] = where.get(f, 0) + c
        if address == begin:
            count["on"] = True
        elif address == end:
            count["on"] = False
            ins_steps.append(count["ins"] - count["i0"])
            cyc_steps.append(count["cyc"] - count["c0"])
            count["i0"], count["c0"] = count["ins"], count["cyc"]
            if len(cyc_steps) == N_STEPS:
                uc.emu_stop()
        count["prev"] = (address, size, dis.get(address, ""))

    uc.hook_add(unicorn.UC_HOOK_CODE, hook)
    if model == "M4":
        uc.reg_write(A.UC_ARM_REG_C1_C0_2, 0xF << 20)  # CPACR: the FPU on
    try:
        uc.emu_start(syms["_start"] | 1, 0xFFFFFFFE, count=50_000_000)
    except unicorn.UcError as e:
        pc = uc.reg_read(A.UC_ARM_REG_PC)
        raise SystemExit(f"{model}: {e} at 0x{pc:x}: {dis.get(pc, '?')} (after {count['prev']})") from None
    return ins_steps, cyc_steps


def sizes(work: Path, P: str, cpu: list[str]) -> tuple[int, int]:
    obj = work / "obs.o"
    subprocess.run(
        [
            "arm-none-eabi-gcc",
            *cpu,
            "-mthumb",
            "-Os",
            "-std=c99",
            "-fstack-usage",
            "-c",
            "-o",
            str(obj),
            str(work / f"{P}.c"),
        ],
        check=True,
        cwd=work,
    )
    text, data, _bss = (
        int(v)
        for v in subprocess.run(["arm-none-eabi-size", str(obj)], capture_output=True, text=True)
        .stdout.splitlines()[1]
        .split()[:3]
    )
    su = (work / "obs.su").read_text()
    frame = max((int(m) for m in re.findall(rf"{P}_step\t(\d+)", su)), default=0)
    return text + data, frame


def speed_fields(obs: Any) -> list[int]:
    """The state fields the "at bound" path sets at their bound (module docstring)."""
    bounded = [k for k, f in enumerate(obs.state) if f.bound and f.unit == "rad/s"]
    if obs.schedule_state is not None:
        k = obs.index("state", obs.schedule_state)
    elif bounded:
        k = bounded[-1]
    else:
        return []
    return [j for j in bounded if obs.state[j].bound == obs.state[k].bound]


TABLE = {"speeds": [100.0, 1500.0, 3050.0, 3800.0], "observer_gain": [400.0, 600.0, 1000.0, 1500.0]}


def table_gains(d: Any, fam: Any) -> Any:
    """The flux family's 4-breakpoint gain table of tests/common/test_fixed_point.py (a tuned table's
    layout: `codegen --gains TABLE`), for the "PRESET+table" rows."""
    import json

    from sensorless.design.gain_table import read_gain_table

    doc = {
        "format": "sensorless-gain-table/2",
        "drive": {"name": d.name, "kind": d.kind, "sha256": d.digest},
        "law": "schedule",
        "gains": {**TABLE, "pll_bandwidth": 1000.0},
        "envelope": {},
        "points": [],
        "summary": {},
    }
    with tempfile.TemporaryDirectory() as tmp:
        f = Path(tmp) / "table.json"
        f.write_text(json.dumps(doc))
        return fam.gains(d, table=read_gain_table(f), table_file="table.json")


def main(presets: list[str]) -> None:
    from sensorless.design.drive import load_drive
    from sensorless.design.registry import family_of
    from sensorless.reports.codegen.fixed_generate import fixed_model, generate_fixed
    from sensorless.reports.codegen.generate import Provenance, generate

    cols = "".join(f" {p + ' mean':>14s} {p + ' worst':>14s}" for p in PATHS)
    print(
        f"{'preset':14s} {'core':5s} {'precision':9s} {'instr/step':>10s}{cols} {'flash B':>8s} {'RAM B':>6s}"
    )
    print("(instr/step: mean over the accepted samples; the other columns: estimated cycles per step)")
    for name in presets:
        d = load_drive(name.removesuffix("+table"))
        fam = family_of(d)
        gains = table_gains(d, fam) if name.endswith("+table") else None
        setup = fam.runtime(d, gains if gains is not None else fam.gains(d))
        model = fixed_model(d, gains, setup)
        fx = model.program(setup)
        prov = Provenance(d.name, d.file, d.digest, "bench")
        P = d.name
        obs = setup.observer
        n_x = len(obs.state)
        meas = model.meas[:, -N_CLEAN * 50 :: 50].copy()
        # x 50: rejected, the step coasts; then plausible samples again, the speed at its bound
        meas = np.hstack([meas, 50.0 * meas[:, :N_GLITCH], meas[:, :N_BOUND]])
        raw = fx.to_raw(meas, "meas").T
        at = speed_fields(obs)
        b = np.asarray(obs.bounds()(setup.p)).ravel()
        x_run = model.data(setup)[0]
        x_at = np.asarray(x_run[:, x_run.shape[1] - N_CLEAN * 50], float).copy()  # before the first sample
        sign = 1.0 if not at or x_at[at[0]] >= 0 else -1.0
        x_at[at] = sign * b[at]
        ang = [k for k, f in enumerate(obs.state) if f.bound.strip() == "pi"]
        # behind by BEHIND after the period's prediction at the excess speed
        behind = sign * BEHIND + d.T_s * (
            x_at[at[0]] - x_run[at[0], x_run.shape[1] - N_CLEAN * 50] if at else 0.0
        )
        x_at[ang] = (x_at[ang] - behind + np.pi) % (2 * np.pi) - np.pi
        x_raw = fx.to_raw(x_at[:, None], "x").ravel()
        for core, prec in (("M0", "fixed"), ("M4", "float")):
            with tempfile.TemporaryDirectory() as tmp:
                work = Path(tmp)
                if prec == "fixed":
                    files = generate_fixed(setup, model, prov, P)
                    rows = ", ".join("{" + ", ".join(str(int(v)) for v in r) + "}" for r in raw)
                    at_bound = "".join(
                        f"            bench_obs.x.{f.name} = {int(x_raw[j])};\n"
                        for j, f in enumerate(obs.state)
                    )
                    init = f"(void){P}_init(&bench_obs, &{P}_default_params)"
                    ram_struct = 4 * (n_x + len(fx.params))  # the state and the parameter struct
                    cpu = ["-mcpu=cortex-m0plus"]
                else:
                    files = generate(setup, prov, precision="float", prefix=P)
                    rows = ", ".join("{" + ", ".join(f"{v:.9g}f" for v in r) + "}" for r in meas.T)
                    at_bound = "".join(
                        f"            bench_obs.x.{f.name} = {float(x_at[j])!r}f;\n"
                        for j, f in enumerate(obs.state)
                    )
                    init = f"(void){P}_init(&bench_obs, &{P}_default_params)"
                    m = re.search(rf"#define {P.upper()}_N_COEF (\d+)", files[f"{P}.h"])
                    ram_struct = 4 * (n_x + (int(m.group(1)) if m else 0))
                    cpu = ["-mcpu=cortex-m4", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard"]
                samples = f'#include "{P}.h"\nconst {P}_input bench_in[{N_STEPS}] = {{{rows}}};\n'
                elf = build(work, P, files, samples, init, at_bound, cpu)
                where: dict[str, int] = {}
                ins, cyc = emulate(elf, core, where if prec == "fixed" else None)
                flash, frame = sizes(work, P, cpu)
                label = core + ("+" if core == "M0" else "F")
                per_path = ""
                for path, (lo, hi) in PATHS.items():
                    c = cyc[lo:hi] if path != "at bound" or at else []
                    per_path += f" {np.mean(c):14.0f} {max(c):14d}" if c else f" {'-':>14s} {'-':>14s}"
                print(
                    f"{name:14s} {label:5s} {prec:9s} {np.mean(ins[:N_CLEAN]):10.0f}{per_path} {flash:8d} "
                    f"{ram_struct + frame:6d}",
                    flush=True,
                )
                if where:  # where the accepted steps' cycles go (a helper inlined counts as the step)
                    top = sorted(where.items(), key=lambda kv: -kv[1])
                    print(
                        "    where (accepted, cycles/step): "
                        + ", ".join(f"{f} {c / N_CLEAN:.0f}" for f, c in top if c / N_CLEAN >= 1),
                        flush=True,
                    )


if __name__ == "__main__":
    main(sys.argv[1:] or ["outrunner270", "outrunner270+table", "hubmotor48", "piippo2008", "deangelo2006"])
