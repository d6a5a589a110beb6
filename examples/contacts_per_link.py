"""Where the hand touches: the estimated contacts of a grasp, link by link, and an HTML replay.

Runs one stored grasp through the load test with the ``mesh_sdf`` estimator and the ``qp``
allocator, then reports, for the last control cycle, every link that carries contacts: how many
points (at most K = 5) and the force the QP commands on the object through that link,

    f_link = sum_i f_i  [N, world frame],

so that palm, finger sides and fingertips can be told apart. With ``--html PATH`` the whole run
is written as a standalone meshcat animation (hand, object, contacts, force arrows) that opens
in a browser without a network.

Run:  python examples/contacts_per_link.py [--object 065-f_cups] [--grasp-type precision]
          [--html run.html] [--quick]
"""

from __future__ import annotations

import argparse

import numpy as np

from wholehand import TrialSpec, load_hand, load_object, protocol_for, run_trial, write_html


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--object", default="077_rubiks_cube")
    parser.add_argument("--grasp", type=int, default=0)
    parser.add_argument("--grasp-type", default="power", help="power or precision")
    parser.add_argument("--html", default=None, help="write the run as an HTML animation here")
    parser.add_argument("--quick", action="store_true", help="shortened stages (a smoke run)")
    args = parser.parse_args()

    hand, obj = load_hand("allegro_right"), load_object(args.object)
    spec = TrialSpec(
        object=obj.name,
        grasp=args.grasp,
        grasp_type=args.grasp_type,
        theta_deg=0.0,
        protocol_params=protocol_for("tiny" if args.quick else "full"),
    )
    record = run_trial(spec, hand=hand, obj=obj)
    last = len(record.rows["t"]) - 1
    c = record.contacts_at(last)
    links = c["contact_link"]
    print(f"{obj.name} {args.grasp_type} grasp {args.grasp}, cycle {last}: {len(links)} contacts")
    print(f"{'link':<16} {'kind':<10} {'points':>6} {'|f| N':>7}")
    for link in np.unique(links):
        rows = links == link
        name = hand.link_names[link]
        kind = "fingertip" if hand.link_fingertip[link] else "finger"
        kind = "palm" if name == hand.palm_link else kind
        force = float(np.linalg.norm(c["contact_f"][rows].sum(axis=0)))
        print(f"{name:<16} {kind:<10} {int(rows.sum()):>6} {force:>7.2f}")
    if args.html:
        print(f"replay: {write_html(record, args.html, hand=hand, obj=obj)}")


if __name__ == "__main__":
    main()
