"""Contact detection: kinematic hysteresis and durations, vGRF thresholds, S1_Hopping agreement."""

import numpy as np

from stablemofusion.footskate.contacts import (KinematicContactConfig, clean_durations, contact_f1,
                                               contacts_from_underpressure_labels, contacts_from_vgrf,
                                               kinematic_contacts)


def _feet_motion(heights: np.ndarray, speeds: np.ndarray, fps: float = 20.0) -> np.ndarray:
    """(T, 22, 3) with every foot joint at ``heights`` (T,) moving along X at ``speeds`` (T,) m/s."""
    T = len(heights)
    j = np.zeros((T, 22, 3))
    j[:, :, 1] = 1.0
    x = np.concatenate([[0.0], np.cumsum(speeds[1:] / fps)])
    for k in (7, 10, 8, 11):
        j[:, k, 0] = x
        j[:, k, 1] = heights
    return j


def test_durations():
    m = np.array([1, 1, 0, 1, 0, 0, 0, 1, 1, 1], bool)
    out = clean_durations(m[:, None], min_on=3, min_gap=2)[:, 0]
    assert out.tolist() == [1, 1, 1, 1, 0, 0, 0, 1, 1, 1]  # gap of 1 filled, then short runs survive merged


def test_kinematic_planted_then_lifted():
    h = np.r_[np.zeros(20), np.linspace(0, 0.3, 10), np.full(10, 0.3), np.linspace(0.3, 0, 10), np.zeros(10)]
    c = kinematic_contacts(_feet_motion(h, np.zeros(len(h))), 20.0)
    assert c.shape == (60, 4)
    assert c[:18].all() and not c[35:45].any() and c[-5:].all()


def test_kinematic_hysteresis_keeps_contact_through_small_bumps():
    h = np.zeros(40)
    h[20] = 0.06  # between height_on (0.05) and height_off (0.08): contact persists
    assert kinematic_contacts(_feet_motion(h, np.zeros(40)), 20.0)[:, 1].all()
    h[20] = 0.2
    assert not kinematic_contacts(_feet_motion(h, np.zeros(40)), 20.0, config=KinematicContactConfig(min_gap=0.0))[20, 1]


def test_kinematic_fast_feet_are_not_planted():
    c = kinematic_contacts(_feet_motion(np.zeros(40), np.full(40, 2.0)), 20.0)
    assert not c.any()


def test_vgrf_contacts_thresholds():
    f = np.zeros((10, 2, 16))
    f[:, 0, :6] = 0.5 / 6  # left heel carries half the weight
    f[:, 1, 6:] = 0.5 / 10  # right forefoot the other half
    f[5:, 1] = 0.004  # then the right foot is lifted (0.064 < 10 %)
    c = contacts_from_vgrf(f, 20.0, smooth=0.0)
    assert c[:, 0].all() and not c[:, 1].any()
    assert c[:5, 3].all() and not c[5:, 3].any() and not c[:, 2].any()


def test_both_routes_on_s1(s1):
    true = contacts_from_underpressure_labels(s1["contacts"])
    assert contact_f1(contacts_from_vgrf(s1["forces"], 100.0), true) > 0.95  # measured forces -> contacts
    kin = kinematic_contacts(s1["joints"], 100.0, foot_joints=(21, 22, 17, 18), up_axis=2)
    assert contact_f1(kin, true) > 0.85
