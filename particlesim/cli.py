"""Command line: ``python -m particlesim.cli main`` runs the main job (the quarter-car free response, the
particle report of its bodies, Krang falling on fixed wheels, then the full vehicle on a four-post rig);
``quarter-car``, ``particles``, ``krang`` and ``vehicle-ride`` run one of them."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

__all__ = ["main"]


def _particles(out: Path) -> None:
    from .reports.particles import format_particles, particle_report

    t0 = time.perf_counter()
    summary = particle_report(out)
    print("Equivalent particle systems of the quarter-car bodies (Attia Table 1; layout assumptions in")
    print("particlesim/scenes/quarter_car.py). Positions in each body's frame [m], masses [kg].\n")
    print(format_particles(out))
    print("\nReproduction residuals (relative) and physical consistency:\n")
    print((out / "particles_summary.md").read_text())
    for s in summary:
        for w in s["warnings"]:
            print(f"note: {w}")
    print(f"\nwrote {out / 'particles.csv'}, {out / 'particles_summary.json'}, {out / 'particles_summary.md'} "
          f"in {time.perf_counter() - t0:.1f} s")


def _krang(out: Path) -> None:
    from .reports.krang_fall import krang_fall

    print("\nKrang on fixed wheels (18 joints) falling under gravity for 2 s, against its MuJoCo C twin ...")
    f = krang_fall(out, progress=sys.stdout.isatty())  # a progress bar only on a terminal, not in logs
    ours, mj = f["ours"], f["mujoco_c"]
    print(f"  particlesim dopri5 (rtol 1e-10): {ours['accepted_steps']} steps, run {ours['run_s']:.2f} s "
          f"(compile + first run {ours['compile_plus_first_run_s']:.1f} s)")
    print(f"  MuJoCo C RK4 dt = {mj['dt']:g} s: run {mj['run_s']:.2f} s")
    print(f"  max |q_ours - q_mujoco| over all joints and 2 s: {f['max_abs_joint_deviation_rad']:.2e} rad "
          f"({f['joint_with_max_deviation']})")
    print(f"  total energy {f['energy_start_J']:.3f} J -> {f['energy_end_J']:.3f} J (viscous friction "
          f"{f['viscous_friction_Nms_per_rad']:g} N m s/rad on every joint)")
    print(f"wrote {out / 'krang_fall.csv'}, {out / 'krang_fall.png'}, {out / 'krang_fall.json'}")


def _quarter_car(out: Path) -> None:
    from .reports.quarter_car import DURATION, quarter_car_report

    print(f"\nQuarter-car double wishbone (Attia 3): free response from rest, {DURATION:g} s ...")
    f = quarter_car_report(out, progress=sys.stdout.isatty())
    print(f"  {f['particles_free']} free particles, {f['constraints']} constraints, {f['degrees_of_freedom']} degrees "
          f"of freedom; {f['solver']} rtol {f['rtol']:g}: {f['accepted_steps']} steps, run {f['run_s']:.2f} s "
          f"(compile {f['compile_s']:.1f} s)")
    print(f"  chassis displacement: final {f['final_displacement_m'] * 1e3:.2f} mm; acceleration at release "
          f"{f['initial_acceleration_m_s2']:.3f} m/s^2, peak {f['peak_acceleration_m_s2']:.2f} m/s^2")
    print(f"  largest constraint residual over the run: {f['max_position_constraint_residual']:.1e}")
    print(f"wrote {out / 'quarter_car.csv'}, {out / 'quarter_car.png'}, {out / 'quarter_car.json'}")


def _vehicle_ride(out: Path) -> None:
    from .reports.vehicle_ride import DURATION, ROAD_CLASS, SPEED, vehicle_ride_report

    print(f"\nFull vehicle (HMMWV corners, 10 DOF) on a four-post rig, {DURATION:g} s: a 5 cm bump under the front "
          f"wheels, then ISO 8608 class {ROAD_CLASS} at {SPEED:g} m/s ...")
    f = vehicle_ride_report(out, progress=sys.stdout.isatty())
    modes = ", ".join(f"{m['mode']} {m['frequency_Hz']:.2f} Hz (zeta {m['damping_ratio']:.2f})" for m in f["modes"][:3])
    hop = f["modes"][3]
    print(f"  ride modes: {modes}; {hop['mode']} {hop['frequency_Hz']:.1f} Hz")
    print(f"  {f['solver']} rtol {f['rtol']:g}, located tyre switches: {f['accepted_steps']} steps, run "
          f"{f['run_s']:.2f} s (compile {f['compile_s']:.1f} s; rest and modes {f['rest_s'] + f['modes_s']:.1f} s)")
    off = [s for s in f["switches"] if not s["in_contact_after"]]
    print(f"  RMS chassis vertical acceleration on the random road {f['rms_acceleration_iso_m_s2']:.3f} m/s^2; "
          f"peak wheel load {max(f['peak_wheel_loads_N'].values()) / 1e3:.1f} kN; "
          + (f"{len(off)} tyre lift-offs from {off[0]['t_s']:.3f} s" if off else "no tyre left its post"))
    print(f"wrote {out / 'vehicle_ride.csv'}, {out / 'vehicle_ride.png'}, {out / 'vehicle_ride.json'}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="particlesim", description=__doc__)
    parser.add_argument("job", nargs="?", default="main", choices=["main", "quarter-car", "particles", "krang",
                                                                   "vehicle-ride"])
    parser.add_argument("--out", type=Path, default=Path("out"), help="output folder (default: out/)")
    args = parser.parse_args(argv)
    if args.job in ("main", "quarter-car"):
        _quarter_car(args.out)
    if args.job in ("main", "particles"):
        _particles(args.out)
    if args.job in ("main", "krang"):
        _krang(args.out)
    if args.job in ("main", "vehicle-ride"):
        _vehicle_ride(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
