"""A contact-estimator plug-in of your own: the paper's estimator fed a noisy object pose.

The paper tests constant pose errors only (Sec. IV-B-2) and leaves time-varying tracking noise
open. This script defines ``NoisyPoseEstimator``, which perturbs the object pose it is given by a
fresh random rotation (about the centre of mass) and translation every cycle before calling the
built-in ``mesh_sdf`` estimator, passes the class itself to a trial (no entry point needed for
experiments; see docs/plugins.md to publish one), and compares noise levels:

    wMo_seen = wMo @ T_k,   T_k: rotation ~ N(0, sigma_rot) about a random axis through the
                            centre of mass, translation ~ N(0, sigma_trans) per axis, new each cycle

(Without a plug-in, the loop's ``PoseNoise`` observation filter adds the same kind of noise to the
pose every stage sees, once per tracker frame: ``wholehand run --pose-noise-mm 1 --pose-noise-deg
1``. This script shows how an estimator of your own plugs in.)

Run:  python examples/tracking_noise_estimator.py [--object 077_rubiks_cube] [--quick]
"""

from __future__ import annotations

import argparse

import numpy as np
import pinocchio as pin

from wholehand import (
    ContactEstimator,
    ContactSet,
    HandKinematics,
    HandModel,
    ObjectModel,
    TrialSpec,
    load_hand,
    load_object,
    protocol_for,
    record_row,
    registry,
    run_trial,
)


class NoisyPoseEstimator(ContactEstimator):
    """``mesh_sdf`` on an object pose with fresh Gaussian noise each cycle.

    Args:
        hand, obj: the models (passed by the trial set-up like to any estimator).
        sigma_rot_deg: standard deviation of the rotation angle [deg].
        sigma_trans_mm: standard deviation of the translation per axis [mm].
        seed: seeds the noise.
        **params: passed on to the ``mesh_sdf`` estimator (``d_thresh``, ``k``, ...).
    """

    def __init__(
        self,
        hand: HandModel,
        obj: ObjectModel,
        sigma_rot_deg: float = 0.0,
        sigma_trans_mm: float = 0.0,
        seed: int = 0,
        **params: float,
    ) -> None:
        self.inner = registry.load("contact_estimators", "mesh_sdf", hand=hand, obj=obj, **params)
        self.com = obj.com
        self.sigma_rot = np.deg2rad(sigma_rot_deg)
        self.sigma_trans = 1e-3 * sigma_trans_mm
        self.rng = np.random.default_rng(seed)

    def estimate(
        self, kinematics: HandKinematics, wMo: np.ndarray, stamp: float = 0.0
    ) -> ContactSet:
        axis = self.rng.standard_normal(3)
        R = pin.exp3(self.rng.normal(scale=self.sigma_rot) * axis / np.linalg.norm(axis))
        offset = np.eye(4)
        offset[:3, :3] = R
        offset[:3, 3] = self.com - R @ self.com + self.rng.normal(scale=self.sigma_trans, size=3)
        return self.inner.estimate(kinematics, wMo @ offset, stamp)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--object", default="077_rubiks_cube")
    parser.add_argument("--grasp", type=int, default=0)
    parser.add_argument("--quick", action="store_true", help="shortened stages (a smoke run)")
    args = parser.parse_args()

    hand, obj = load_hand("allegro_right"), load_object(args.object)
    protocol = protocol_for("tiny" if args.quick else "full")
    print(f"{obj.name} grasp {args.grasp}: load test with per-cycle pose noise")
    print(f"{'sigma deg':>9} {'sigma mm':>8} {'held':<5} {'lost in':<10} {'moved mm':>9}")
    for sigma_rot, sigma_trans in ((0.0, 0.0), (2.0, 1.0), (5.0, 2.0), (10.0, 4.0)):
        spec = TrialSpec(
            object=obj.name,
            grasp=args.grasp,
            theta_deg=0.0,
            estimator=NoisyPoseEstimator,
            estimator_params={"sigma_rot_deg": sigma_rot, "sigma_trans_mm": sigma_trans},
            protocol_params=protocol,
        )
        row = record_row(run_trial(spec, hand=hand, obj=obj))
        print(
            f"{sigma_rot:>9.1f} {sigma_trans:>8.1f} {'yes' if row['held'] else 'no':<5} "
            f"{row['failure_stage'] or '-':<10} {row['final_displacement_mm']:>9.1f}"
        )


if __name__ == "__main__":
    main()
