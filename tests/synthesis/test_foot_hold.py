"""Feet held through a change of pose (`synthesis.foot_hold`): a planted foot keeps the
motion it had before the change, from where the change put it; the hold fades after the
span; chunk by chunk gives the whole call's frames."""

from __future__ import annotations

import numpy as np

from graphsvc.motion import quat
from graphsvc.motion.kinematics import forward_kinematics
from graphsvc.synthesis.foot_hold import FootHold
from tests.conftest import still_motion


def _swung(T: int = 20):
    """The T-pose standing still, and the same with the left hip swinging forward a
    little more each frame (the change that would drag the planted left foot)."""
    m = still_motion(T)
    rot, trans = m.rotations.astype(np.float64), m.translations.astype(np.float64)
    hip = m.skeleton.names.index("l_hip")
    changed = rot.copy()
    angle = np.linspace(0.0, 0.3, T)
    changed[:, hip] = quat.from_axis_angle(np.tile([1.0, 0.0, 0.0], (T, 1)), angle)
    return m.skeleton, rot, trans, changed


def test_a_planted_foot_stays_where_the_changed_pose_put_it_and_is_let_go_after_the_span():
    sk, rot, trans, changed = _swung()
    contacts = np.zeros((20, 2), dtype=bool)
    contacts[:12, 0] = True  # the left foot planted for 12 frames, then free
    held = FootHold(sk, 30.0).apply(changed, trans, rot, trans, contacts)
    ankle = sk.names.index("l_ankle")
    pos = forward_kinematics(held, trans, sk.parents)[1][:, ankle]
    swung = forward_kinematics(changed, trans, sk.parents)[1][:, ankle]
    # in the span: the standing foot did not move, so the held one does not either (to
    # the 0.1 mm the IK keeps a straight leg short of full stretch)
    np.testing.assert_allclose(pos[:12], np.repeat(swung[:1], 12, axis=0), atol=2e-4)
    assert np.linalg.norm(swung[11] - swung[0]) > 0.05  # (unheld it would have slid 5 cm and more)
    # after it, the hold fades out over FOOT_BLEND_S (3 frames at 30 Hz), then it is gone
    np.testing.assert_allclose(held[16:], changed[16:], atol=1e-12)
    assert not np.allclose(held[12], changed[12])
    # the right leg was never held
    np.testing.assert_allclose(held[:, sk.names.index("r_hip")], changed[:, sk.names.index("r_hip")], atol=1e-12)


def test_chunk_by_chunk_is_the_whole_call():
    sk, rot, trans, changed = _swung()
    contacts = np.zeros((20, 2), dtype=bool)
    contacts[2:15, 0] = True
    contacts[5:9, 1] = True
    whole = FootHold(sk, 30.0).apply(changed, trans, rot, trans, contacts)
    hold = FootHold(sk, 30.0)
    parts = [
        hold.apply(changed[a:b], trans[a:b], rot[a:b], trans[a:b], contacts[a:b])
        for a, b in ((0, 3), (3, 4), (4, 11), (11, 20))
    ]
    np.testing.assert_array_equal(np.concatenate(parts), whole)
