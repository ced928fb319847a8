"""The learner's s in state-only runs: the sim state ‖ a frozen embedding of the task's instruction."""

import numpy as np

from accrue.sim import STATE_DIM, make_vec_env
from stages.steps.common import per_task_features


def test_task_embedding_is_appended_fixed_and_differs_between_tasks():
    obs = make_vec_env("nist/rect_peg", num_envs=3, seed=0).reset()
    feats = per_task_features({"encoder": "none", "task_features": 16}, ["nist/rect_peg", "nist/gear"])
    rect, gear = feats["nist/rect_peg"](obs), feats["nist/gear"](obs)
    assert rect.shape == gear.shape == (3, STATE_DIM + 16) and rect.dtype == np.float32
    np.testing.assert_array_equal(rect[:, :STATE_DIM], obs["state"])
    np.testing.assert_array_equal(rect[:, STATE_DIM:], np.broadcast_to(rect[0, STATE_DIM:], (3, 16)))
    assert not np.allclose(rect[0, STATE_DIM:], gear[0, STATE_DIM:])
    # the same task gets the same code in another step or process (a pure function of the instruction)
    again = per_task_features({"encoder": "none", "task_features": 16}, ["nist/rect_peg"])["nist/rect_peg"](obs)
    np.testing.assert_array_equal(again, rect)


def test_without_task_features_s_is_the_state():
    obs = make_vec_env("nist/gear", num_envs=2, seed=1).reset()
    for config in ({"encoder": "none"}, {"encoder": "none", "task_features": 0}):
        s = per_task_features(config, ["nist/gear"])["nist/gear"](obs)
        np.testing.assert_array_equal(s, obs["state"])
