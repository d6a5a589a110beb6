"""Compare force-regulation methods on one stored grasp under the paper's perturbation protocol.

Every method holds the same grasp (same seed: the same random pull axis) through settle, the
six-direction load test (0.1 m g for 1 s along +-x, +-y, +-z), a spring-damper pull toward a pose
rotated by theta, and the load test again. The methods differ only in the allocator plug-in:

    qp              tau = J_act^T f_act, f from the QP over the contacts estimated on every link
    fingertip_only  the same QP over contacts on the distal links only
    feedforward     f allocated once on MuJoCo's contacts at the start, tau held constant
    impedance       the same one-off f, applied by a Cartesian spring toward fixed targets

Run:  python examples/compare_methods.py [--object 065-f_cups] [--grasp 1] [--theta 90]
      python examples/compare_methods.py --quick      (shortened stages, seconds)
"""

from __future__ import annotations

import argparse

from wholehand import TrialSpec, load_hand, load_object, protocol_for, record_row, run_trial

METHODS = ("qp", "fingertip_only", "feedforward", "impedance")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--object", default="006_mustard_bottle")
    parser.add_argument("--grasp", type=int, default=0)
    parser.add_argument("--theta", type=float, default=90.0, help="rotation of the pull [deg]")
    parser.add_argument("--seed", type=int, default=0, help="seeds the pull axis")
    parser.add_argument("--quick", action="store_true", help="shortened stages (a smoke run)")
    args = parser.parse_args()

    hand, obj = load_hand("allegro_right"), load_object(args.object)
    protocol = protocol_for("tiny" if args.quick else "full")
    print(f"{obj.name} grasp {args.grasp}, pull by {args.theta:g} deg, seed {args.seed}")
    print(f"{'method':<16} {'held':<5} {'lost in':<10} {'contacts':>8} {'moved mm':>9}")
    for method in METHODS:
        spec = TrialSpec(
            object=obj.name,
            grasp=args.grasp,
            allocator=method,
            theta_deg=args.theta,
            seed=args.seed,
            protocol_params=protocol,
        )
        row = record_row(run_trial(spec, hand=hand, obj=obj))
        print(
            f"{method:<16} {'yes' if row['held'] else 'no':<5} {row['failure_stage'] or '-':<10} "
            f"{row['contacts_mean']:>8.1f} {row['final_displacement_mm']:>9.1f}"
        )


if __name__ == "__main__":
    main()
