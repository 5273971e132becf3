"""DAgger (the ``dagger`` member): a real short run on table1-train learns to overtake where
always-follow never succeeds, the same seed gives the same bytes, the OVERTAKE threshold is in the
exported weights, and the shipped member loads with one call and evaluates."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch")

from overtakezoo import zoo  # noqa: E402
from overtakezoo.benchmark.suite_groups import load_training
from overtakezoo.envs import CRASH, OVERTAKE, SUCCESS  # noqa: E402
from overtakezoo.envs.suites import load_suite  # noqa: E402
from overtakezoo.zoo.members.learned import MLPDecider  # noqa: E402
from overtakezoo.zoo.train import dagger  # noqa: E402
from overtakezoo.zoo.train.contract import TrainError, check_card  # noqa: E402

SHORT = {"steps": 2, "episodes": 24, "grad_steps": 400, "select_scenarios": 40, "offsets": [-1.0, 0.0, 1.0]}


def outcomes(decider, suite, n):
    from overtakezoo.benchmark.run.runner import run_suite

    return np.asarray(run_suite(suite, decider, progress=False, limit=n).per["outcome"])


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("dagger")
    trained = dagger.train(
        load_training("table1-train"), suite_name="table1-train", out=out, overrides=SHORT, progress=False
    )
    return trained, out


@pytest.mark.slow
def test_a_short_run_learns_to_overtake_on_the_training_split(short_run):
    trained, out = short_run
    suite = load_suite("table1-train")
    got = outcomes(trained.decider(suite.config), suite, 200)
    follow = outcomes(zoo.load("always-follow", suite.config), suite, 200)
    assert (follow == SUCCESS).mean() == 0.0  # following never reaches the goal in time
    score = (got == SUCCESS).mean() - 2 * (got == CRASH).mean()
    assert (got == SUCCESS).mean() > 0.5 and score > 0.3, (got == SUCCESS).mean()
    check_card(trained.card)
    assert (out / "dagger.npz").is_file() and (out / "log.csv").is_file()
    log = trained.card["training"]["log"]
    decay = trained.card["hyperparameters"]["beta_decay"]
    assert 0 < decay < 1 and [r["beta"] for r in log] == [1.0, decay]  # the oracle alone, then the mixture
    assert log[1]["states"] > log[0]["states"]  # the student's states are added, not replacing


@pytest.mark.slow
def test_the_same_seed_gives_the_same_bytes(short_run, tmp_path):
    trained, _ = short_run
    again = dagger.train(
        load_training("table1-train"), suite_name="table1-train", out=tmp_path, overrides=SHORT, progress=False
    )
    assert again.npz == trained.npz


@pytest.mark.slow
def test_the_chosen_threshold_is_baked_into_the_exported_overtake_logit(short_run):
    trained, _ = short_run
    offset = trained.card["training"]["overtake_logit_offset"]
    assert offset in SHORT["offsets"]
    sel = trained.card["training"]["threshold_selection"]
    assert (
        sel["offsets"][int(np.argmax(sel["score"]))] == offset
        or max(sel["score"]) == sel["score"][sel["offsets"].index(offset)]
    )
    suite = load_suite("table1-train")
    x = dagger.features(_obs(suite), suite.config)
    import torch

    with torch.no_grad():
        raw = trained.module(torch.from_numpy(x)).double().numpy()
    shipped = trained.net(x.astype(np.float64))
    assert np.allclose(shipped[:, OVERTAKE], raw[:, OVERTAKE], atol=1e-5)  # module is the shipped copy
    # The shipped bias is the fitted one plus the offset: removing it gives back the fit.
    fitted = dagger.with_offset(trained.module, -offset)
    with torch.no_grad():
        back = fitted(torch.from_numpy(x)).double().numpy()
    assert np.allclose(back[:, OVERTAKE] + offset, shipped[:, OVERTAKE], atol=1e-5)


def _obs(suite):
    from overtakezoo.envs.core import OvertakeCore

    core = OvertakeCore(suite.config)
    return core.reset(suite.scenarios().take(np.arange(8)))


def test_the_shipped_member_loads_with_one_call_and_evaluates():
    suite = load_suite("table1")
    d = zoo.load("dagger", suite.config)
    assert isinstance(d, MLPDecider) and d.action_repeat == 10 and d.use_mask
    check_card(d.model_card)
    assert d.model_card["train_suite"]["name"] == "core-train"
    got = outcomes(d, suite, 50)
    assert len(got) == 50 and (got == SUCCESS).mean() > 0.5


def test_bad_requests_are_one_line_errors():
    suites = load_training("table1-train")
    with pytest.raises(TrainError, match="trains dagger"):
        dagger.train(suites, member="bc")
    with pytest.raises(TrainError, match="no checkpoint"):
        dagger.train(suites, resume="x.pt")


def test_a_frame_stack_member_reads_its_last_decisions_and_forgets_them_at_reset(tmp_path):
    """The memory variant: trained with frame_stack = 3, it loads as a StackedMLPDecider whose input
    is its last 3 decisions' features; reset zeroes a row's memory, and the same episode gives the
    same modes whether or not the runner drops finished rows."""
    from overtakezoo.zoo.members.learned import StackedMLPDecider, load_pretrained

    tiny = {"steps": 1, "episodes": 4, "grad_steps": 20, "select_scenarios": 8, "offsets": [0.0], "frame_stack": 3}
    trained = dagger.train(
        load_training("table1-train"), suite_name="table1-train", out=tmp_path, overrides=tiny, progress=False
    )
    assert trained.card["frame_stack"] == 3
    check_card(trained.card)
    suite = load_suite("table1-train")
    d = load_pretrained("dagger", suite.config, directory=tmp_path)
    assert isinstance(d, StackedMLPDecider) and d.net.in_features == 3 * d.history.shape[2]
    obs = _obs(suite)
    d.reset()
    d.act(obs)
    d.act(obs)
    assert np.abs(d.history[:, 2]).sum() == 0 and np.array_equal(d.history[:, 0], d.history[:, 1])
    d.reset(np.arange(8) < 4)
    assert np.abs(d.history[:4]).sum() == 0 and np.abs(d.history[4:]).sum() > 0
    a = outcomes(d, suite, 16)
    b = outcomes(load_pretrained("dagger", suite.config, directory=tmp_path), suite, 16)
    assert np.array_equal(a, b)


@pytest.mark.slow
def test_on_multi_av_roads_the_joint_oracle_teaches_every_av(tmp_path):
    """On duel-train (two AVs a road) the teacher is the joint oracle and one student drives both
    seats: a short run succeeds jointly on most training roads, without AV-AV crashes."""
    from overtakezoo.benchmark.run.runner import run_indices

    suites = load_training("duel-train")
    trained = dagger.train(suites, suite_name="duel-train", out=tmp_path, overrides=SHORT, progress=False)
    check_card(trained.card)
    per_split = trained.card["training"]["threshold_selection"]["per_split"]
    assert list(per_split) == ["duel-train"]
    suite = suites[0]
    per = run_indices(suite, trained.decider(suite.config), np.arange(60))
    joint = (np.asarray(per["outcome"]).reshape(suite.num_avs, -1) == SUCCESS).all(axis=0)
    follow = run_indices(suite, zoo.load("always-follow", suite.config), np.arange(60))
    assert (np.asarray(follow["outcome"]) != SUCCESS).all()
    assert joint.mean() > 0.7, joint.mean()
