"""The authors' observation and action layout, and how a converted agent absorbs it.

The reference lists the legs of its observation in its body-tree order (fl, ml, fr, mr, rr, rl)
and of its action in its actuator order (fl, fr, rr, rl, mr, ml); epoet's hexapod uses fl, fr,
ml, mr, rl, rr for both (`LEGS`, the order of conf/agent/hexapod.yaml's joints). Its six contact flags were always 0 (reference defect 1,
docs/reference.md), so its agents never learned to read them.

A converted agent takes epoet's observation and gives epoet's action: the permutation is folded
into the first layer's input weights and the last layer's outputs, and the contact inputs get
zero weight (with a normaliser, their constant normalised value moves into the first bias). So
the converted file is an ordinary agent file that every consumer (evaluate, render, t-SNE, the
MLflow model) runs as it is; the file records the layout it was trained with as provenance.
"""

from __future__ import annotations

import numpy as np

from epoet.envs.spaces import observation_size

LEGS = ("fl", "fr", "ml", "mr", "rl", "rr")  # epoet's hexapod: its joints <leg>_<segment> ...
SEGMENTS = ("coxa", "femur", "tibia")  # ... and its feet <leg>_tibia, in this order
OBS_LEGS = ("fl", "ml", "fr", "mr", "rr", "rl")  # the reference's body-tree order
ACT_LEGS = ("fl", "fr", "rr", "rl", "mr", "ml")  # the reference's actuator order
LAYOUT = {
    "observation_legs": list(OBS_LEGS),
    "action_legs": list(ACT_LEGS),
    "contact_flags": "always 0 in training (zero weight here)",
    "converted_to": list(LEGS),
}

_JOINTS = len(LEGS) * len(SEGMENTS)
ACT_DIM = _JOINTS  # the hexapod's sizes, by epoet.envs.spaces' rule
OBS_DIM = observation_size(_JOINTS, len(LEGS))
CONTACTS = np.arange(OBS_DIM - len(LEGS), OBS_DIM)  # epoet's contact inputs (the last six)


def _joint_order(ref_legs: tuple[str, ...]) -> np.ndarray:
    """For each of epoet's joints, its index in a joint list ordered by `ref_legs`."""
    n = len(SEGMENTS)
    return np.array([ref_legs.index(leg) * n + s for leg in LEGS for s in range(n)])


def observation_source() -> np.ndarray:
    """For each of epoet's observation entries, the reference observation entry it is (joint
    angles and velocities re-ordered, torso and contact entries in place)."""
    joints = _joint_order(OBS_LEGS)
    src = np.arange(OBS_DIM)
    src[:_JOINTS] = joints
    src[_JOINTS : 2 * _JOINTS] = _JOINTS + joints
    contacts = np.array([OBS_LEGS.index(leg) for leg in LEGS])
    src[CONTACTS] = CONTACTS[0] + contacts
    return src


def action_source() -> np.ndarray:
    """For each of epoet's actions, the reference action it is."""
    return _joint_order(ACT_LEGS)


def fold_input(
    weight: np.ndarray,
    bias: np.ndarray,
    contact_value: np.ndarray | None = None,
    extra_inputs: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """A first layer (weight: (outputs, reference inputs), torch's layout) re-ordered to take
    epoet's observation (followed by `extra_inputs` unchanged inputs, e.g. a critic's action,
    which the caller permutes). The contact inputs get zero weight; `contact_value` is what
    the layer saw for them (after any normaliser; None: 0), moved into the bias."""
    obs = weight[:, :OBS_DIM][:, observation_source()]
    folded_bias = bias.copy()
    if contact_value is not None:
        folded_bias = folded_bias + obs[:, CONTACTS] @ contact_value
    obs[:, CONTACTS] = 0.0
    return np.concatenate([obs, weight[:, OBS_DIM : OBS_DIM + extra_inputs]], axis=1), folded_bias


def fold_critic_input(weight: np.ndarray, bias: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A Q network's first layer (inputs: the reference's observation, then its action)
    re-ordered to take epoet's observation and action."""
    folded, folded_bias = fold_input(weight, bias, extra_inputs=ACT_DIM)
    folded[:, OBS_DIM:] = folded[:, OBS_DIM:][:, action_source()]
    return folded, folded_bias


def fold_output_rows(weight: np.ndarray, bias: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A last layer (torch's layout) whose rows are groups of ACT_DIM actions in the reference's
    order (a mean, and for SAC a log-std after it), re-ordered to epoet's."""
    groups = weight.shape[0] // ACT_DIM
    rows = np.concatenate([g * ACT_DIM + action_source() for g in range(groups)])
    return weight[rows], bias[rows]


def es_theta(theta: np.ndarray, sizes: tuple[int, ...]) -> np.ndarray:
    """An ES parameter vector (epoet's flat layout, weights (in, out) then bias per layer, which
    is also the reference's) re-ordered to take epoet's observation and give epoet's action."""
    from epoet.rollout.policy import unflatten

    out = np.array(theta, dtype=np.float64)
    layers = unflatten(out, sizes)
    w_first, b_first = layers[0]
    folded, _ = fold_input(w_first.T.copy(), b_first)
    w_first[...] = folded.T
    w_last, b_last = layers[-1]
    rows_w, rows_b = fold_output_rows(w_last.T.copy(), b_last.copy())
    w_last[...], b_last[...] = rows_w.T, rows_b
    return out
