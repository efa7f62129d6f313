"""The DQN agent: double-Q target by hand, masking, replay n-step returns, config round trip, exact resume."""

from __future__ import annotations

import json
import shutil
import time

import numpy as np
import pandas as pd
import pytest
import torch
from pydantic import ValidationError

from tests.conftest import REPO, write_grid_city
from uavplace.dataset.build import build_city
from uavplace.dataset.bundle import load_bundle
from uavplace.ingest.pipeline import ingest_city
from uavplace.rl.agent.config import DQNConfig, preset_config
from uavplace.rl.agent.dqn import DQN, DQNPolicy, genie_move_loss, masked_argmax, to_tensor
from uavplace.rl.agent.network import FoveaQNetwork, MeanQ, QNetwork
from uavplace.rl.agent.pqn import q_lambda_returns
from uavplace.rl.agent.replay import Batch, ReplayBuffer
from uavplace.rl.agent.runs import load_policy, read_run_json
from uavplace.rl.agent.train import Trainer
from uavplace.rl.tasks.placement.config import EnvConfig
from uavplace.rl.tasks.placement.env import BatchedEnv
from uavplace.rl.world.cities import plan_cities
from uavplace.rl.world.maps import MapSet
from uavplace.schemas import InputError
from uavplace.schemas.bundle import BuildConfig


class TableNet(torch.nn.Module):
    """Q values looked up from the first pixel of the observation: a network whose outputs we choose."""

    def __init__(self, table: dict[int, list[float]]) -> None:
        super().__init__()
        self.table = table

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return torch.tensor([self.table[int(k)] for k in obs[:, 0, 0, 0]], dtype=torch.float32)


def test_double_q_target_by_hand():
    agent = DQN(DQNConfig(gamma=0.9, hidden=8, conv_channels=(4, 4, 4)), in_channels=1, window=21)
    # Online prefers action 3 at state 7 but it is illegal there: the legal argmax is action 1.
    agent.online = TableNet({7: [0.0, 5.0, 1.0, 9.0], 8: [2.0, 0.0, 0.0, 0.0]})
    agent.target = TableNet({7: [10.0, 20.0, 30.0, 40.0], 8: [-1.0, 3.0, 3.0, 3.0]})
    next_obs = np.zeros((3, 1, 21, 21), np.float32)
    next_obs[:, 0, 0, 0] = [7, 8, 7]
    batch = Batch(
        obs=next_obs,
        action=np.zeros(3, np.int64),
        reward=np.array([1.0, 2.0, 3.0], np.float32),
        discount=np.array([0.9, 0.81, 0.0], np.float32),
        next_obs=next_obs,
        next_mask=np.array([[1, 1, 1, 0], [1, 1, 1, 1], [1, 1, 1, 1]], bool),
    )
    # row 0: online picks a*=1 among legal, target says 20 -> 1 + 0.9 * 20; row 1: a*=0, target -1;
    # row 2: terminal (discount 0) -> the reward alone.
    np.testing.assert_allclose(agent.td_target(batch).numpy(), [1 + 0.9 * 20, 2 - 0.81, 3.0], rtol=1e-6)


def test_masked_argmax_never_picks_an_illegal_move():
    rng = np.random.default_rng(0)
    q = torch.from_numpy(rng.normal(size=(500, 4)).astype(np.float32))
    mask = rng.random((500, 4)) < 0.5
    mask[np.arange(500), rng.integers(0, 4, 500)] = True
    a = masked_argmax(q, torch.from_numpy(mask)).numpy()
    assert mask[np.arange(500), a].all()
    agent = DQN(DQNConfig(hidden=8, conv_channels=(4, 4, 4)), in_channels=2, window=61)
    obs = rng.normal(size=(500, 2, 61, 61)).astype(np.float32)
    for eps in (0.0, 0.5, 1.0):
        acts = agent.act(obs, mask, eps, last=rng.integers(-1, 4, 500), rng=rng)
        assert mask[np.arange(500), acts].all()


def test_forward_eval_is_the_eval_mode_forward_whatever_the_mode():
    torch.manual_seed(0)
    net = QNetwork(2, 21, hidden=16, channels=(4, 8, 8), dropout=0.5)
    for _ in range(3):  # move the running statistics away from their initial values
        net(torch.randn(16, 2, 21, 21) * 40 + 10)
    x = torch.randn(5, 2, 21, 21) * 40
    with torch.no_grad():
        folded = net.forward_eval(x)  # in train mode: dropout and batch statistics must not enter
        assert net.training
        torch.testing.assert_close(folded, net.eval()(x), rtol=1e-4, atol=1e-4)
        last = net.to(memory_format=torch.channels_last).forward_eval(x.contiguous(memory_format=torch.channels_last))
        torch.testing.assert_close(last, folded, rtol=1e-4, atol=1e-4)
    with pytest.raises(TypeError, match="recurrent"):
        QNetwork(2, 21, hidden=16, channels=(4, 8, 8), recurrent=True).forward_eval(x)


def test_fast_dqn_computes_what_the_plain_one_does():
    """DQN(fast=True) (channels-last, folded batch norms, fused Adam and clipping) against fast=False from the same
    weights on the same batch: the same targets, Q values, moves, gradients and step. (Over many updates the two drift
    apart as any change of summation order makes them: the convolutions' biases before a batch norm have no true
    gradient, so Adam moves them by its step size in the direction of rounding noise.)"""
    rng = np.random.default_rng(0)
    config = DQNConfig(hidden=16, conv_channels=(4, 8, 8), batch_size=12)
    agents = {}
    for fast in (False, True):
        torch.manual_seed(0)
        agents[fast] = DQN(config, in_channels=2, window=21, fast=fast)
    assert agents[True].optimizer.param_groups[0]["fused"] and not agents[False].optimizer.param_groups[0]["fused"]
    for agent in agents.values():  # running statistics away from their start, the same in both
        agent.online.train()
        with torch.no_grad():
            agent.online(torch.from_numpy(rng.integers(0, 250, (32, 2, 21, 21)).astype(np.float32)))
        rng = np.random.default_rng(0)
    obs, next_obs = (rng.integers(0, 250, (12, 2, 21, 21), dtype=np.uint8) for _ in range(2))
    mask = rng.random((12, 4)) < 0.7
    mask[:, 0] = True
    batch = Batch(obs=obs, action=rng.integers(0, 4, 12), reward=rng.normal(size=12).astype(np.float32),
                  discount=np.full(12, 0.99, np.float32), next_obs=next_obs, next_mask=mask)  # fmt: skip
    torch.testing.assert_close(agents[True].td_target(batch), agents[False].td_target(batch), rtol=1e-4, atol=1e-4)
    q = {fast: agent.q_values(obs) for fast, agent in agents.items()}
    torch.testing.assert_close(q[True], q[False], rtol=1e-4, atol=1e-4)
    moves = {fast: agent.act(obs, mask, 0.0, np.full(12, -1), np.random.default_rng(0)) for fast, agent in agents.items()}
    np.testing.assert_array_equal(moves[True], moves[False])
    before = [p.detach().clone() for p in agents[False].online.parameters()]
    for agent in agents.values():
        torch.manual_seed(1)  # the same dropout masks
        agent.update(batch, 1e-3)
    params = {fast: list(agent.online.parameters()) for fast, agent in agents.items()}
    for was, a, b in zip(before, params[False], params[True], strict=True):
        torch.testing.assert_close(b.grad, a.grad, rtol=1e-3, atol=1e-5)
        real = a.grad.abs() > 1e-4  # gradients above rounding noise: Adam's first step is -lr * sign(grad) there
        torch.testing.assert_close(b[real], a[real], rtol=0, atol=1e-6)
        assert torch.allclose(a[real], was[real] - 1e-3 * a.grad[real].sign(), atol=1e-6)


def test_fast_dqn_keeps_its_fused_step_through_a_checkpoint():
    config = DQNConfig(hidden=8, conv_channels=(4, 4, 4))
    plain, fast = DQN(config, 2, 21, fast=False), DQN(config, 2, 21, fast=True)
    fast.load_optimizer(plain.optimizer.state_dict())  # a checkpoint written by plain Adam
    assert fast.optimizer.param_groups[0]["fused"]
    plain.load_optimizer(fast.optimizer.state_dict())
    assert not plain.optimizer.param_groups[0]["fused"]


def test_replay_n_step_returns_and_truncation():
    n_env, gamma = 2, 0.5
    rb = ReplayBuffer(capacity=40, num_envs=n_env, obs_shape=(1, 1, 1), t_max=5, n_step=3, gamma=gamma)
    mask = np.ones((n_env, 4), bool)
    # env 0: rewards 1, 2, 3, 4, ... never ends; env 1: ends terminated at its 2nd step, then truncated at its 4th.
    for t in range(8):
        obs = np.array([[[[t]]], [[[100 + t]]]], np.uint8)
        term = np.array([False, t == 1])
        trunc = np.array([False, t == 3])
        final = np.array([[[[200 + t]]]], np.uint8) if t == 3 else np.zeros((0, 1, 1, 1), np.uint8)
        rb.add(
            obs,
            mask,
            np.zeros(n_env, np.int8),
            np.array([t + 1, 10 * (t + 1)], np.float32),
            term,
            trunc,
            final,
            mask[:1] if t == 3 else mask[:0],
        )
    batch = rb.sample(400, np.random.default_rng(0))
    for o, r, d, no in zip(batch.obs[:, 0, 0, 0], batch.reward, batch.discount, batch.next_obs[:, 0, 0, 0], strict=True):
        if o < 100:  # env 0 at step t=o: r_t + g r_{t+1} + g^2 r_{t+2}, bootstrap from obs t+3
            assert r == pytest.approx((o + 1) + gamma * (o + 2) + gamma**2 * (o + 3))
            assert d == pytest.approx(gamma**3) and no == o + 3
        elif o == 100:  # env 1, t=0: rewards 10, 20 then terminated
            assert r == pytest.approx(10 + gamma * 20) and d == 0.0
        elif o == 101:
            assert r == pytest.approx(20) and d == 0.0
        elif o == 102:  # t=2: rewards 30, 40 then truncated: bootstrap from the final observation 203
            assert r == pytest.approx(30 + gamma * 40) and d == pytest.approx(gamma**2) and no == 203
    assert {int(o) for o in batch.obs[:, 0, 0, 0]} >= {0, 1, 100, 101, 102}


def test_q_lambda_returns_by_hand():
    """Two envs over 3 moves: env 0 runs on (a blend of the return ahead and the next bootstrap, then the bootstrap
    where the envs stand); env 1 terminates at move 0 and is truncated at move 2 (its final observation's Q)."""
    g, lam = 0.5, 0.25
    reward = np.array([[1.0, 10.0], [2.0, 20.0], [3.0, 30.0]], np.float32)
    term = np.array([[False, True], [False, False], [False, False]])
    trunc = np.array([[False, False], [False, False], [False, True]])
    q_next = np.array([[4.0, 99.0], [5.0, 7.0], [6.0, 99.0]], np.float32)  # 99: read nowhere (after an end)
    q_final = np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 8.0]], np.float32)
    out = q_lambda_returns(reward, term, trunc, q_next, q_final, g, lam)
    g2 = 3 + g * 6  # env 0, last move: one-step from where it stands
    g1 = 2 + g * (lam * g2 + (1 - lam) * 5)
    g0 = 1 + g * (lam * g1 + (1 - lam) * 4)
    h2 = 30 + g * 8  # env 1: truncated, bootstrap from its final observation (not from the next slot's episode)
    h1 = 20 + g * (lam * h2 + (1 - lam) * 7)
    np.testing.assert_allclose(out, [[g0, 10.0], [g1, h1], [g2, h2]], rtol=1e-6)
    # lambda 0 is the one-step target everywhere, lambda 1 the discounted return to the rollout's end
    np.testing.assert_allclose(q_lambda_returns(reward, term, trunc, q_next, q_final, g, 0.0)[:2, 0], [1 + g * 4, 2 + g * 5])
    np.testing.assert_allclose(q_lambda_returns(reward, term, trunc, q_next, q_final, g, 1.0)[0, 0], 1 + g * 2 + g * g * g2)


def test_config_round_trip_and_presets():
    for name in ("paper", "fast", "best", "best-pqn", "best-dqn"):
        cfg = preset_config(name, seed=3)
        again = DQNConfig.model_validate_json(cfg.model_dump_json())
        assert again == cfg and again.preset == name
    paper = preset_config("paper")
    assert (paper.batch_size, paper.train_every, paper.buffer_size, paper.gamma, paper.dropout) == (20, 3, 500_000, 0.99, 0.4)
    assert paper.env.t_max == 800 and paper.env.rotate and paper.eps_end == 0.0 and paper.test_epsilon == 0.096
    assert preset_config("best").recurrent and preset_config("best-pqn").learner == "pqn"
    best = preset_config("best")
    assert best.env.homing_channel and best.train_revisit_penalty == best.test_revisit_penalty == 1.0 and best.gamma == 0.98
    gru = {"recurrent": False, "num_envs": 128, "rollout_steps": 16, "train_revisit_penalty": 0.0, "preset": "best-pqn"}
    gru["gamma"] = 0.99
    gru["env"] = best.env.model_copy(update={"homing_channel": False})
    assert best.model_copy(update=gru) == preset_config("best-pqn")
    with pytest.raises(ValueError, match="unknown preset"):
        preset_config("huge")


@pytest.fixture(scope="module")
def city_root(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("agent")
    ingest_city(write_grid_city(tmp / "raw", nx=12, ny=10, n_tx=4, outputs=("power",), seed=5), tmp / "p", name="tiny")
    build_city("tiny", BuildConfig(grid_m=4.0, altitude_m=10.0, noise_dbm=-58.0, role="train", val_users=1), tmp / "p")
    return tmp / "p"


def _tiny_config(**env: object) -> DQNConfig:
    return preset_config(
        "fast", total_steps=256, num_envs=8, buffer_size=512, batch_size=16, train_every=4, learning_starts=64,
        eval_every=128, eval_episodes=16, hidden=16, conv_channels=(4, 8, 8), env={"t_max": 30, "rotate": True} | env,
    )  # fmt: skip


PQN = {"learner": "pqn", "rollout_steps": 5, "epochs": 2, "layer_norm": True, "aux_genie": 1.0}
GRU = PQN | {"recurrent": True}
#: The hybrid's belief channel, its maps predicted by the shipped physics tier (fast on the tiny city).
HYBRID = {"belief_channel": True, "belief_predictor": str(REPO / "data" / "agents" / "searcher" / "predictor.json")}


@pytest.mark.parametrize(
    ("env", "learner"),
    [({}, {}), ({"context_zoom": 3, "homing_channel": True}, {}), ({}, PQN), ({}, GRU), (HYBRID, GRU)],
    ids=["plain", "context-homing", "pqn", "gru", "hybrid"],
)
@pytest.mark.slow
def test_resume_continues_exactly(tmp_path, city_root, env, learner):
    """Train 256 steps straight, or stop at 96 and 200 and resume each time: identical networks and next actions
    (with context and homing channels too, whose memory of blocks and of the best cell the checkpoint keeps; with
    PQN, stopped mid-rollout; with a recurrent PQN network, whose state in each env the checkpoint keeps; and with
    the hybrid's belief channel, whose beliefs the checkpoint keeps)."""

    def config() -> DQNConfig:
        return _tiny_config(**env).model_copy(update=learner)

    straight = Trainer(config(), ["tiny"], city_root, tmp_path / "a")
    straight.run()
    half = Trainer(config(), ["tiny"], city_root, tmp_path / "b", command="uavrl train --until 96")
    half.run(stop_at=96)  # a planned stop between evaluations (`--until 96`) checkpoints there
    doc = json.loads((tmp_path / "b" / "run.json").read_text())
    assert doc["train_split"] == "train" and doc["eval_split"] == "val" and doc["datasets"]["tiny"]
    checkpoint = tmp_path / "b" / "checkpoints" / "last" / "checkpoint.json"
    doc = json.loads(checkpoint.read_text())
    assert doc["wall_s"] > 0
    offset = 1e9  # as if the first part had taken 31 years: no run's own time comes near it, however busy the machine
    checkpoint.write_text(json.dumps(doc | {"wall_s": offset}))
    # A checkpoint from before the env counted visits kept the visited cells; it resumes (counts above 1 only
    # matter to a revisit penalty or cost, which this run has not).
    with np.load(checkpoint.with_name("env.npz")) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["visited"] = arrays.pop("visits") > 0
    np.savez(checkpoint.with_name("env.npz"), **arrays)
    t0 = time.perf_counter()
    Trainer(config(), ["tiny"], city_root, tmp_path / "b", command="uavrl train --resume b --until 200").run(
        resume=True, stop_at=200
    )
    resumed = Trainer(config(), ["tiny"], city_root, tmp_path / "b", command="uavrl train --resume b")
    resumed.run(resume=True)
    assert read_run_json(tmp_path / "b").commands == [  # every command that trained it, in order
        "uavrl train --until 96",
        "uavrl train --resume b --until 200 (from step 96)",
        "uavrl train --resume b (from step 200)",
    ]
    assert resumed.state.step == straight.state.step == 256
    # The run's own clock goes on from the checkpoint's: the evaluations after the stop count the time before it.
    evals = pd.read_parquet(tmp_path / "b" / "eval.parquet")
    assert (
        evals.wall_s.is_monotonic_increasing
        and offset < evals.wall_s.min() < evals.wall_s.max() < offset + time.perf_counter() - t0
    )
    assert 0 < pd.read_parquet(tmp_path / "a" / "eval.parquet").wall_s.max() < offset
    # PQN: 6 rollouts of 8 x 5 moves, 2 epochs of 2 batches of 16 moves (recurrent: of 3 env rollouts, 15 moves)
    assert straight.agent.updates == (24 if learner else 48)
    if learner.get("recurrent"):
        assert straight.agent.hidden.abs().sum() > 0
        torch.testing.assert_close(straight.agent.hidden, resumed.agent.hidden)
    for a, b in zip(straight.agent.online.state_dict().values(), resumed.agent.online.state_dict().values(), strict=True):
        torch.testing.assert_close(a, b)
    obs, mask = straight.env.observe(), straight.env.action_mask()
    np.testing.assert_array_equal(obs, resumed.env.observe())
    rng_a, rng_b = np.random.default_rng(1), np.random.default_rng(1)
    last = np.full(8, -1)
    np.testing.assert_array_equal(straight.agent.act(obs, mask, 0.0, last, rng_a), resumed.agent.act(obs, mask, 0.0, last, rng_b))
    policy, cfg = load_policy(tmp_path / "a" / "checkpoints" / "best.pt")
    assert cfg == straight.config and policy.act(obs, mask, straight.env).shape == (8,)
    for name in set(straight.env.state_arrays) - {"visits"}:  # visits: counted from the old checkpoint's cells
        np.testing.assert_array_equal(getattr(straight.env, name), getattr(resumed.env, name), err_msg=name)
    if env.get("belief_channel"):
        np.testing.assert_array_equal(straight.env.belief.cover, resumed.env.belief.cover)
    metrics = tmp_path / "a" / "metrics.parquet"

    df = pd.read_parquet(metrics)
    assert {"step", "episode", "sinr_gain_db", "sinr_gain_mean100_db", "success", "loss", "epsilon", "lr"} <= set(df.columns)


def test_uavrl_train_cli(tmp_path, city_root):
    from click.testing import CliRunner

    from uavplace.cli import uavrl

    run = CliRunner().invoke
    assert "--resume" in run(uavrl, ["train", "--help"]).output
    args = [
        "train",
        "--dataset",
        "tiny",
        "--root",
        str(city_root),
        "--preset",
        "fast",
        "--steps",
        "96",
        "--out",
        str(tmp_path),
        "--quiet",
    ]
    res = run(uavrl, args)
    assert res.exit_code == 0, res.output
    (run_dir,) = (p for p in tmp_path.iterdir() if p.is_dir())  # beside it only its lock file, .NAME.lock
    assert "fast-dqn-s0" in run_dir.name and "last evaluation" in res.output
    assert {"run.json", "metrics.parquet", "eval.parquet", "checkpoints"} <= {p.name for p in run_dir.iterdir()}
    assert (run_dir / "checkpoints" / "best.pt").is_file()
    res = run(uavrl, [*args, "--name", run_dir.name])
    assert res.exit_code == 2 and "exists" in res.output
    res = run(uavrl, [*args[:-1], "--name", "logged"])  # not a terminal and not --quiet: plain lines for a log
    assert res.exit_code == 0 and "train logged: step 96/96 ep " in res.output, res.output
    assert "loss nan" not in res.output  # before the first update: "loss -"
    from uavplace.infra.files import exclusive_folder

    with exclusive_folder(tmp_path / "busy", "training run"):  # another command holds the name (or resumes the run)
        res = run(uavrl, [*args, "--name", "busy"])
        assert res.exit_code == 2 and "another process is working on this training run now" in res.output
        assert not (tmp_path / "busy").exists()  # refused before anything was claimed or written
        res = run(uavrl, ["train", "--resume", str(run_dir), "--root", str(city_root), "--quiet"])
        assert res.exit_code == 0  # another run's lock is not this one's
    with exclusive_folder(run_dir, "training run"):
        res = run(uavrl, ["train", "--resume", str(run_dir), "--root", str(city_root), "--quiet"])
        assert res.exit_code == 2 and "another process is working on this training run now" in res.output
    res = run(uavrl, ["train", "--dataset", "nowhere", "--root", str(city_root), "--out", str(tmp_path)])
    assert res.exit_code != 0 and "nowhere: dataset: no ingested city or corpus" in res.output
    # the city rebuilt at another noise level: a resume names it, and refuses it with --strict
    import shutil

    other = tmp_path / "rebuilt"
    shutil.copytree(city_root, other)
    build_city("tiny", BuildConfig(grid_m=4.0, altitude_m=10.0, noise_dbm=-60.0, role="train", val_users=1), other)
    res = run(uavrl, ["train", "--resume", str(run_dir), "--root", str(other), "--strict", "--quiet"])
    assert res.exit_code == 2 and "noise -60 dBm (trained at -58 dBm)" in res.output, res.output


def test_folded_batch_norm_gives_the_same_q_values():
    """The acting copy of the paper network (batch norm folded into the convolutions) computes the same Q values."""
    from uavplace.rl.agent.network import QNetwork

    torch.manual_seed(0)
    net = QNetwork(2, 21, hidden=16, channels=(4, 8, 8))
    net.train()
    for _ in range(3):  # move the running statistics away from their initial values
        net(torch.randn(16, 2, 21, 21) * 40 + 10)
    net.eval()
    fused = net.fused()
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in fused.modules())
    x = torch.randn(5, 2, 21, 21) * 40
    with torch.no_grad():
        torch.testing.assert_close(fused(x), net(x), rtol=1e-4, atol=1e-4)
    assert net.training is False and any(isinstance(m, torch.nn.BatchNorm2d) for m in net.modules())  # untouched


def test_fovea_network_sees_a_centred_fovea_and_surround():

    for window, fovea in ((61, 15), (21, 7), (15, 15)):
        net = FoveaQNetwork(2, window, hidden=8, fovea=fovea)
        assert (window - net.kernel) // net.stride + 1 == fovea and net(torch.zeros(3, 2, window, window)).shape == (3, 4)
        assert (window - 1 - (net.stride * (fovea - 1) + net.kernel - 1)) == 0  # the pooled grid spans the window exactly
    with pytest.raises(ValueError, match="odd"):
        FoveaQNetwork(2, 21, fovea=8)


def _fovea_tells_apart(a: torch.Tensor, b: torch.Tensor, **views: bool) -> bool:
    """Whether a fovea network (fovea 15 on a 61-cell window, with ``views``: extremes, middle) gives windows ``a`` and
    ``b`` different Q values."""
    torch.manual_seed(0)
    net = FoveaQNetwork(2, 61, hidden=8, fovea=15, **views).eval()
    with torch.no_grad():
        return not torch.equal(net(a), net(b))


def test_pooled_extremes_keep_a_lone_cell_visible():
    """A corner block of the surround holding +50 and -50 averages to what an empty one does: the mean-pooled network
    cannot tell them apart, the one with max- and min-pooled views can."""
    empty = torch.zeros(1, 2, 61, 61)
    mixed = empty.clone()
    mixed[0, 1, 0, 0], mixed[0, 1, 0, 1] = 50.0, -50.0  # both in the first pooled block only (kernel 5, stride 4)
    for extremes in (False, True):
        assert _fovea_tells_apart(empty, mixed, extremes=extremes) is extremes


def test_middle_view_sees_a_lane_the_surround_blurs():
    """Two windows alike in the centre and in every surround block's mean (one cell of +50 moved within a block, 11
    cells from the UAV: a lane beyond the centre) are one to the fovea network and two with its middle view; the middle
    view needs a window of 2 * fovea + 1 cells."""
    a = torch.zeros(1, 2, 61, 61)
    b = a.clone()
    a[0, 1, 30, 41], b[0, 1, 30, 42] = 50.0, 50.0  # both in (only) the surround block of columns 40-44; the centre: 23-37
    for middle in (False, True):
        assert _fovea_tells_apart(a, b, middle=middle) is middle
    with pytest.raises(ValueError, match="2 \\* fovea \\+ 1"):
        FoveaQNetwork(2, 21, fovea=11, middle=True)


def test_recurrent_network_unrolls_as_it_steps():
    """The learner's view (``unroll`` over a rollout) gives the states the actor's (``step`` by step) gave, the state
    restarting from zeros where an episode starts; a recurrent network has no Q without its state."""
    torch.manual_seed(0)
    net = FoveaQNetwork(2, 21, hidden=8, fovea=7, recurrent=True, layer_norm=True).eval()
    steps, n = 6, 3
    obs = torch.randn(steps, n, 2, 21, 21) * 40
    first = torch.zeros(steps, n, dtype=torch.bool)
    first[3, 1] = True  # row 1 starts an episode at move 3
    h0 = torch.randn(n, 8)
    with torch.no_grad():
        states = net.unroll(obs, h0, first)
        h = h0
        for t in range(steps):
            q, h = net.step(obs[t], torch.where(first[t, :, None], net.initial_state(n), h))
            torch.testing.assert_close(states[t], h)
            torch.testing.assert_close(net.head(states[t]), q)
        other = net.unroll(obs, torch.randn(n, 8), first)  # another past: row 1 forgets it once its episode restarts
    assert not torch.allclose(other[2], states[2])
    torch.testing.assert_close(other[3:, 1], states[3:, 1])
    assert not torch.allclose(other[3:, 0], states[3:, 0])
    with pytest.raises(TypeError, match="state"):
        net(obs[0])
    with pytest.raises(InputError, match="learner=pqn"):
        preset_config("best-dqn", recurrent=True)


def test_recurrent_policy_keeps_a_state_per_row(city_root):
    """A recurrent ``DQNPolicy`` carries each row's state from move to move (the same observation, another history,
    other Q values) and restarts it in the rows ``reset`` names only."""
    torch.manual_seed(0)
    cfg = EnvConfig(window=21)
    env = BatchedEnv(MapSet([load_bundle("tiny", root=city_root)], cfg), 4)
    obs, info = env.reset(seed=0)
    policy = DQNPolicy(FoveaQNetwork(cfg.num_channels, 21, hidden=8, fovea=7, recurrent=True), epsilon=0.0)
    policy.reset(np.arange(4), 4)
    assert policy.hidden.abs().sum() == 0
    policy.act(obs, info["action_mask"], env)
    after_one = policy.hidden.clone()
    assert (after_one.abs().sum(dim=1) > 0).all()
    policy.act(obs, info["action_mask"], env)  # the same observations again: the state moves on
    assert not torch.allclose(policy.hidden, after_one)
    policy.reset(np.array([2]), 4)
    assert policy.hidden[2].abs().sum() == 0 and (policy.hidden[[0, 1, 3]].abs().sum(dim=1) > 0).all()


@pytest.mark.parametrize("arch", ["fovea", "conv"])
def test_a_bfloat16_policy_acts_near_float32_and_each_row_as_in_any_batch(city_root, arch):
    """``precision="bfloat16"``: the features under bfloat16 autocast stay near float32's, and a row's state and move
    are the same to the bit whether it plays with every row or with some of them (Ray's pieces change the batch)."""
    cfg = EnvConfig(window=21)
    env = BatchedEnv(MapSet([load_bundle("tiny", root=city_root)], cfg), 6)
    obs, info = env.reset(seed=0)
    torch.manual_seed(1)
    if arch == "fovea":
        net = FoveaQNetwork(cfg.num_channels, 21, hidden=32, fovea=7, recurrent=True)
    else:
        net = QNetwork(cfg.num_channels, 21, hidden=32, channels=(8, 16, 16), recurrent=True)
    with pytest.raises(ValueError, match="unknown network precision 'half'"):
        DQNPolicy(net, precision="half")
    full, low, pieces = (DQNPolicy(net, epsilon=0.0, precision=p) for p in ("float32", "bfloat16", "bfloat16"))
    for policy in (full, low, pieces):
        policy.reset(np.arange(6), 6)
    mask = info["action_mask"]
    for live in ([0, 2, 5], [1, 3, 4]):  # the six rows' first move in two batches of three
        env.exhausted[:] = True
        env.exhausted[live] = False
        pieces.act(obs, mask, env)
    env.exhausted[:] = False
    full.act(obs, mask, env)
    low.act(obs, mask, env)
    assert low.hidden.dtype == torch.float32 and not torch.equal(low.hidden, full.hidden)
    assert torch.allclose(low.hidden, full.hidden, atol=0.05)
    assert torch.equal(pieces.hidden, low.hidden)
    assert np.array_equal(pieces.act(obs, mask, env), low.act(obs, mask, env))  # the second move, all rows together
    assert torch.equal(pieces.hidden, low.hidden)


@pytest.mark.parametrize(
    "learner", [{"learner": "replay", "recurrent": False}, {"recurrent": False}, {}], ids=["replay", "pqn", "pqn-gru"]
)
@pytest.mark.slow
def test_short_training_run_learns(tmp_path, learner):
    """On the embedded tiny city (noisier, so that few cells reach P_T), 15 k steps beat the random walk
    clearly on held-out episodes (drawn with another seed than training's), with either learner (and PQN with a
    recurrent network)."""
    from pathlib import Path

    from uavplace.rl.tasks.placement.learner import validation_set
    from uavplace.rl.tasks.placement.policies import RandomWalkPolicy
    from uavplace.rl.tasks.placement.rollout import run_episodes
    from uavplace.rl.world.stats import summarise

    raw = Path(__file__).resolve().parents[1] / "data" / "raw" / "tiny"
    ingest_city(raw, tmp_path / "p", name="tiny")
    build_city("tiny", BuildConfig(grid_m=4.0, altitude_m=10.0, noise_dbm=-40.0), tmp_path / "p")
    config = preset_config(
        "best", total_steps=15_000, num_envs=16, buffer_size=15_000, batch_size=32, train_every=2, learning_starts=500,
        target_update=1_000, eval_every=5_000, eval_episodes=50, eval_t_max=40, eps_fraction=0.6, lr_start=1e-3,
        lr_end=1e-4, fovea=7, hidden=64, train_revisit_penalty=0.0,
        env={"t_max": 40, "rotate": True, "window": 21, "visited_channel": False, "homing_channel": False,
             "success_bonus": 0.0}, **learner,
    )  # fmt: skip
    # The learner on the paper's two channels and reward: with the visited channel this 15 k-step run on the tiny
    # city reached 27.8 % against the walk's 22.8 %, with the success bonus 32.5 % against 22.8 % (both below the
    # margin); those levers' gains are measured on the corpus (README, lever table).
    trainer = Trainer(config, ["tiny"], tmp_path / "p", tmp_path / "run")
    trainer.run()
    policy, cfg = load_policy(tmp_path / "run" / "checkpoints" / "best.pt", epsilon=0.0)
    # the run's validation maps: all 4 users (the tiny city has no split), rotation off, t_max 40
    maps, _ = validation_set(config, plan_cities([load_bundle("tiny", root=tmp_path / "p")], [], config.eval_split))
    held_out = maps.sample_episodes(400, np.random.default_rng(12345))
    learned = summarise(run_episodes(maps, policy, held_out))["success"]
    walk = summarise(run_episodes(maps, RandomWalkPolicy(seed=1), held_out))["success"]
    assert learned >= walk + 0.1, (learned, walk)


def test_checkpoint_is_one_unit(tmp_path, city_root, monkeypatch):
    """A run killed while writing a checkpoint resumes from the last whole one, and loses no metrics row."""
    straight = Trainer(_tiny_config(), ["tiny"], city_root, tmp_path / "a")
    straight.run()
    Trainer(_tiny_config(), ["tiny"], city_root, tmp_path / "b").run(stop_at=96)

    def killed(self, path):
        raise KeyboardInterrupt("killed while writing the replay")

    monkeypatch.setattr(ReplayBuffer, "save", killed)
    with pytest.raises(KeyboardInterrupt):
        Trainer(_tiny_config(), ["tiny"], city_root, tmp_path / "b").run(resume=True, stop_at=200)
    monkeypatch.undo()
    last = tmp_path / "b" / "checkpoints" / "last"
    assert json.loads((last / "checkpoint.json").read_text())["step"] == 96
    assert sorted(p.name for p in last.parent.iterdir()) == [".last.lock", "best.pt", "last"]
    (tmp_path / "b" / "metrics.parquet").unlink()  # as if killed before the metrics were published
    resumed = Trainer(_tiny_config(), ["tiny"], city_root, tmp_path / "b")
    resumed.run(resume=True)
    pd.testing.assert_frame_equal(
        pd.read_parquet(tmp_path / "a" / "metrics.parquet"), pd.read_parquet(tmp_path / "b" / "metrics.parquet")
    )
    for a, b in zip(straight.agent.online.state_dict().values(), resumed.agent.online.state_dict().values(), strict=True):
        torch.testing.assert_close(a, b)


@pytest.fixture(scope="module")
def corpus_root(tmp_path_factory):
    """A corpus of 3 small cities (c-000, c-001 to train on, c-002 built as val) and a test city."""
    tmp = tmp_path_factory.mktemp("corpus")
    roles = {"c-000": None, "c-001": None, "c-002": "val", "held": "test"}
    for i, (name, city_role) in enumerate(roles.items()):
        raw = write_grid_city(tmp / "raw" / name, nx=12, ny=10, n_tx=3, outputs=("power",), seed=20 + i)
        ingest_city(raw, tmp / "p", name=name)
        build_city(name, BuildConfig(grid_m=4.0, altitude_m=10.0, noise_dbm=-58.0, role=city_role), tmp / "p")
    return tmp / "p"


def test_train_on_a_corpus_selects_on_val_cities_and_refuses_test_cities(tmp_path, corpus_root):
    from click.testing import CliRunner

    from uavplace.cli import uavrl

    run = CliRunner().invoke
    base = ["train", "--root", str(corpus_root), "--preset", "fast", "--steps", "64", "--out", str(tmp_path), "--quiet"]
    settings = ["--set", "num_envs=4", "--set", "eval_every=64", "--set", "eval_episodes=8", "--set", "env.t_max=20"]
    res = run(uavrl, [*base, *settings, "--dataset", "c", "--name", "corpus"])
    assert res.exit_code == 0, res.output
    doc = json.loads((tmp_path / "corpus" / "run.json").read_text())
    assert list(doc["datasets"]) == ["c-000", "c-001"] and list(doc["val_datasets"]) == ["c-002"]
    assert doc["config"]["num_envs"] == 4 and doc["config"]["env"]["t_max"] == 20 and doc["config"]["env"]["rotate"]
    assert doc["train_split"] is None and doc["eval_split"] is None
    # c-002 named twice (a val city of the corpus and --val-dataset) is validated on once, not weighted double
    val = plan_cities(
        [load_bundle(c, root=corpus_root) for c in ("c-000", "c-002")], [load_bundle("c-002", root=corpus_root)], None
    ).val
    assert [b.city for b in val] == ["c-002"]
    for given in (["--dataset", "held"], ["--dataset", "c-000", "--val-dataset", "held"]):
        res = run(uavrl, [*base, *given, "--name", "refused"])
        assert res.exit_code != 0 and "held is a test city" in res.output and "never trained or selected on" in res.output
        assert not (tmp_path / "refused").exists()
    res = run(uavrl, [*base, "--dataset", "c-000", "--set", "env.shaping=x", "--name", "bad"])
    assert res.exit_code == 2 and "shaping" in res.output and not (tmp_path / "bad").exists()
    res = run(uavrl, [*base, "--dataset", "c-000", "--set", "gama=0.5", "--name", "bad"])
    assert res.exit_code == 2 and "'gama=0.5'" in res.output
    res = run(uavrl, [*base, "--dataset", "c", "--set", 'env.city_weights={"oldtown": 3}', "--name", "bad"])
    assert res.exit_code != 0 and "env.city_weights" in res.output and "oldtown" in res.output
    assert not (tmp_path / "bad").exists()


@pytest.mark.parametrize(("weights", "share"), [({}, 0.5), ({"c-001": 3.0}, 0.75), ({"c": 2.0, "c-000": 6.0}, 0.25)])
def test_city_weights_draw_cities_in_proportion(corpus_root, weights, share):
    """c-001's share of the drawn episodes: 1/2 unweighted, 3/4 weighted 3 against 1, and an exact name (c-000: 6)
    wins over its corpus (c: 2); the evaluation protocol draws every user alike."""
    config = preset_config("fast", env={"city_weights": weights})
    maps = MapSet.load(["c-000", "c-001"], config.env_config(), root=str(corpus_root))
    assert len(maps.startable) == 6  # 3 users each: equal weights give equal shares
    v = maps.sample_episodes(20_000, np.random.default_rng(0))[:, 0]
    drawn = np.mean([maps.scenarios[s].city == "c-001" for s in maps.scenario_of(v)])
    assert abs(drawn - share) < 0.015
    assert config.env_config(evaluation=True).city_weights == {}
    with pytest.raises(ValidationError, match="positive"):
        EnvConfig(city_weights={"c": 0.0})


def test_report_refuses_a_city_an_agent_was_selected_on(tmp_path, corpus_root):
    from uavplace.eval.evaluate import ReportConfig
    from uavplace.eval.report import make_report

    config = preset_config("fast", num_envs=4, total_steps=64, eval_every=64, eval_episodes=8, env={"t_max": 20})
    Trainer(config, ["c-000"], corpus_root, tmp_path / "run", val_datasets=["c-002"]).run()
    with pytest.raises(InputError, match="selected its checkpoint in c-002"):
        make_report(
            ReportConfig(dataset="c-002", runs=[str(tmp_path / "run")], episodes=8), tmp_path / "report", root=corpus_root
        )
    assert not (tmp_path / "report").exists()
    from click.testing import CliRunner

    from uavplace.cli import uavrl

    for task in ("placement", "fleet"):  # several cities: refused before the first city's report is written
        res = CliRunner().invoke(uavrl, ["report", "--task", task, "--dataset", "held", "--dataset", "c-002", "--run",
                                         str(tmp_path / "run"), "--root", str(corpus_root), "--episodes", "4",
                                         "--out", str(tmp_path / "reports"), "--quiet"])  # fmt: skip
        assert res.exit_code == 2 and "selected its checkpoint in c-002" in res.output, res.output
        assert not (tmp_path / "reports").exists()


class BackToVisitedNet(torch.nn.Module):
    """Q of a move = 1 + the visited channel at the cell it leads to: a network that prefers cells it has been in,
    so that its plain argmax shuttles between two cells for ever."""

    def __init__(self) -> None:
        super().__init__()
        self.unused = torch.nn.Parameter(torch.zeros(1))  # DQNPolicy reads the device from the parameters

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        from uavplace.rl.world.maps import MOVES

        c = obs.shape[-1] // 2
        return torch.stack([1.0 + obs[:, -2, c + dy, c + dx] for dy, dx in MOVES.tolist()], dim=1)


def test_revisit_penalty_breaks_a_loop(city_root):
    """With the penalty, the greedy move leaves cells it has been in: the looping network's episodes cover more
    cells and succeed more often than its plain argmax, which never leaves its first two cells."""
    from uavplace.rl.tasks.placement.config import EnvConfig
    from uavplace.rl.tasks.placement.rollout import run_episodes
    from uavplace.rl.world.maps import MapSet
    from uavplace.rl.world.stats import summarise

    maps = MapSet.load(["tiny"], EnvConfig(t_max=60, window=21, visited_channel=True, rotate=False), root=str(city_root))
    episodes = maps.sample_episodes(64, np.random.default_rng(3))
    cells, success = {}, {}
    for penalty in (0.0, 10.0):
        policy = DQNPolicy(BackToVisitedNet(), epsilon=0.0, revisit_penalty=penalty)
        df = run_episodes(maps, policy, episodes, num_envs=16, record=np.arange(len(episodes)))
        paths = df.attrs["paths"]  # {episode: cells}
        cells[penalty] = np.array([len({tuple(c) for c in paths[e].tolist()}) for e in df.episode])
        success[penalty] = summarise(df)["success"]
        if penalty == 0:
            failed = ~df.success.to_numpy()
            assert failed.any() and (cells[0.0][failed] <= 2).all()
    assert cells[10.0].mean() > 3 * cells[0.0].mean(), (cells[10.0].mean(), cells[0.0].mean())
    assert success[10.0] > success[0.0] + 0.2, success


class ConstantNet(torch.nn.Module):
    """The same Q values for every observation."""

    def __init__(self, q: list[float]) -> None:
        super().__init__()
        self.q = torch.tensor([q])

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.q.expand(len(obs), -1)


def test_train_revisit_penalty_steers_the_training_moves():
    """In training, ``train_revisit_penalty`` takes that many times each move's earlier visits off its Q before the
    greedy choice: the test rule's penalty in the moves a run learns from (off, or without counts: plain argmax)."""
    obs, mask = np.zeros((3, 2, 21, 21), np.uint8), np.ones((3, 4), bool)
    visits = np.array([[0, 0, 0, 0], [1, 0, 0, 0], [1, 2, 0, 0]], np.uint16)
    last, rng = np.full(3, -1), np.random.default_rng(0)
    moves = {}
    for penalty in (0.0, 1.0):
        agent = DQN(_tiny_config().model_copy(update={"train_revisit_penalty": penalty}), 2, 21)
        agent.online = ConstantNet([1.0, 0.5, 0.2, 0.0])
        moves[penalty] = agent.act(obs, mask, 0.0, last, rng, visits).tolist()
        assert agent.act(obs, mask, 0.0, last, rng).tolist() == [0, 0, 0]
    assert moves == {0.0: [0, 0, 0], 1.0: [0, 1, 2]}


def test_genie_move_loss_by_hand():
    """-log of the probability the logits give the genie's set of moves; rows without a genie move do not count."""
    logits = torch.tensor([[0.0, 0.0, 0.0, 0.0], [2.0, 0.0, 0.0, 0.0], [5.0, 1.0, 1.0, 1.0]])
    genie = torch.tensor([[True, True, False, False], [True, False, False, False], [False, False, False, False]])
    p_second = np.exp(2.0) / (np.exp(2.0) + 3.0)
    expected = (-np.log(0.5) - np.log(p_second)) / 2
    assert genie_move_loss(logits, genie).item() == pytest.approx(expected, rel=1e-6)
    assert genie_move_loss(logits, torch.zeros_like(genie)).item() == 0.0


def test_aux_genie_head_learns_the_genie_moves(tmp_path, city_root):
    """With ``aux_genie`` the replay stores the genie's moves and the auxiliary head learns them (its top move is a
    genie move far more often than a uniform guess's share); the checkpoint holds the head and loads as a policy."""
    config = preset_config(
        "fast", total_steps=3_000, eval_every=3_000, eval_episodes=20, learning_starts=500, train_every=2,
        network="fovea", fovea=7, aux_genie=1.0, env={"t_max": 60, "window": 21},
    )  # fmt: skip
    trainer = Trainer(config, ["tiny"], city_root, tmp_path / "run")
    trainer.run()
    replay = trainer.replay
    idx = np.random.default_rng(0).choice(len(replay), 512, replace=False)
    genie, legal = replay.genie[idx], replay.mask[idx]
    assert genie.any(axis=1).mean() > 0.99
    net = trainer.agent.online.eval()
    with torch.no_grad():
        top = net.aux(net.embed(to_tensor(replay.obs[idx]))).argmax(dim=1).numpy()
    hit = genie[np.arange(len(idx)), top].mean()
    chance = (genie.sum(axis=1) / legal.sum(axis=1)).mean()  # a uniformly random legal move's
    assert hit > chance + 0.15, (hit, chance)
    policy, cfg = load_policy(tmp_path / "run" / "checkpoints" / "best.pt")
    assert cfg.aux_genie == 1.0 and policy.net.aux is not None
    # Acting with a large head weight follows the head's top legal move.
    env = trainer.env
    obs, legal = env.observe(), env.action_mask()
    follower = DQNPolicy(policy.net, epsilon=0.0, aux_weight=1e6)
    with torch.no_grad():
        logits = policy.net.aux(policy.net.embed(to_tensor(obs)))
    expected = logits.masked_fill(~torch.from_numpy(legal), float("-inf")).argmax(dim=1).numpy()
    np.testing.assert_array_equal(follower.act(obs, legal, env), expected)
    with pytest.raises(ValueError, match="genie-move head"):
        DQNPolicy(FoveaQNetwork(2, 21, hidden=8, fovea=7), aux_weight=1.0)  # no head


def snapshot_bytes(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("recurrent", [False, True])
def test_an_ensemble_pools_its_observation_once_and_computes_what_its_members_do(recurrent):
    """Foveated members of one view geometry share the pooled views: the ensemble's features are, to the bit, its
    members' own side by side; members of other geometries each pool their own."""
    torch.manual_seed(0)
    obs = torch.randn(7, 3, 21, 21) * 30
    for fovea in ((5, 5, 5), (5, 7, 5)):
        nets = [FoveaQNetwork(3, window=21, hidden=16, fovea=f, recurrent=recurrent).eval() for f in fovea]
        mean = MeanQ(nets)
        h = torch.randn(7, 48) if recurrent else None
        parts = h.chunk(3, dim=1) if recurrent else (None,) * 3
        with torch.inference_mode():
            alone = torch.cat([net.encode(obs, part) for net, part in zip(nets, parts, strict=True)], dim=1)
            assert torch.equal(mean.encode(obs, h), alone)
            assert torch.equal(mean.embed(obs), torch.cat([net.embed(obs) for net in nets], dim=1))


def test_ensemble_acts_on_the_mean_q_and_plays_like_a_run(tmp_path, corpus_root):
    """``uavrl ensemble`` of two recurrent runs (seeds 0 and 1): each member keeps its own state and the Q values are
    the mean of theirs; the folder reads as an agent, evaluated on the members' validation episodes, and the report
    plays it. Members that differ in more than the seed, or share one, and a training config with an ensemble, are
    refused before anything is written."""
    from click.testing import CliRunner

    from uavplace.cli import uavrl
    from uavplace.eval.evaluate import ReportConfig, load_agent
    from uavplace.eval.report import make_report
    from uavplace.rl.agent.ensemble import build_ensemble

    for seed in (0, 1):
        config = _tiny_config().model_copy(update=GRU | {"seed": seed})
        Trainer(
            config, ["c-000"], corpus_root, tmp_path / f"s{seed}", command=f"uavrl train s{seed}", val_datasets=["c-002"]
        ).run()
    res = CliRunner().invoke(
        uavrl,
        [
            "ensemble",
            str(tmp_path / "s0"),
            str(tmp_path / "s1"),
            "--out",
            str(tmp_path / "e"),
            "--root",
            str(corpus_root),
            "--quiet",
        ],
    )
    assert res.exit_code == 0, res.output
    assert "2 runs; validation" in res.output
    members = [load_policy(tmp_path / f"s{s}" / "checkpoints" / "best.pt")[0].net for s in (0, 1)]
    policy, config = load_policy(tmp_path / "e" / "checkpoints" / "best.pt")
    assert config.ensemble == 2 and config.seed == 0
    cfg = config.env_config(evaluation=True)
    torch.manual_seed(3)
    obs = [torch.randn(5, cfg.num_channels, cfg.window, cfg.window) * 40 for _ in range(3)]
    h = policy.net.initial_state(5)
    hs = [m.initial_state(5) for m in members]
    with torch.no_grad():
        for x in obs:  # three moves: the members' states go on apart
            h = policy.net.encode(x, h)
            hs = [m.encode(x, part) for m, part in zip(members, hs, strict=True)]
            torch.testing.assert_close(h, torch.cat(hs, dim=1))
            torch.testing.assert_close(policy.net.head(h), (members[0].head(hs[0]) + members[1].head(hs[1])) / 2)
    assert not torch.allclose(members[0].head(hs[0]), members[1].head(hs[1]))
    record = read_run_json(tmp_path / "e")
    assert list(record.members) == [str(tmp_path / "s0"), str(tmp_path / "s1")]
    assert list(record.datasets) == ["c-000"] and list(record.val_datasets) == ["c-002"]
    assert record.commands[:2] == ["uavrl train s0", "uavrl train s1"] and len(record.commands) == 3  # then its own
    evals = pd.read_parquet(tmp_path / "e" / "eval.parquet")
    assert len(evals) == 1 and 0 <= evals.success[0] <= 1
    curves = pd.read_parquet(tmp_path / "e" / "metrics.parquet")
    assert set(curves.member) == {"s0", "s1"}
    agent = load_agent(tmp_path / "e", 0.096, 0)
    assert agent.name == "PQN + GRU x 2 (fast)" and agent.best_eval["success"] == evals.success[0]
    report = make_report(ReportConfig(dataset="held", runs=[str(tmp_path / "e")], episodes=8), tmp_path / "r", root=corpus_root)
    assert "PQN + GRU x 2 (fast)" in report.table["method"].tolist()
    with pytest.raises(InputError, match="selected its checkpoint in c-002"):
        make_report(ReportConfig(dataset="c-002", runs=[str(tmp_path / "e")], episodes=8), tmp_path / "r2", root=corpus_root)
    # Refused, with nothing written: a member of another config, the same seed twice, one run, an existing --out.
    config = _tiny_config().model_copy(update=GRU | {"seed": 0, "gamma": 0.9})  # s0's seed: it differs all the same
    Trainer(config, ["c-000"], corpus_root, tmp_path / "g", val_datasets=["c-002"]).run()
    for runs, match in (
        (["s0", "g"], "config.gamma: differs from"),
        (["s0", "s0"], "config.seed: the same settings and seed as"),
        (["s0"], "at least two runs"),
        (["s0", "e"], "already an ensemble"),
    ):
        with pytest.raises(InputError, match=match):
            build_ensemble([tmp_path / r for r in runs], tmp_path / "bad", corpus_root)
        assert not (tmp_path / "bad").exists()
    with pytest.raises(InputError, match="exists"):
        build_ensemble([tmp_path / "s0", tmp_path / "s1"], tmp_path / "e", corpus_root)

    def another_wrote(done: int, total: int) -> None:  # a second `uavrl ensemble --out e2` finishes while this one plays
        if not (tmp_path / "e2").exists():
            shutil.copytree(tmp_path / "e", tmp_path / "e2")

    with pytest.raises(InputError, match="written once"):
        build_ensemble([tmp_path / "s0", tmp_path / "s1"], tmp_path / "e2", corpus_root, on_progress=another_wrote)
    assert snapshot_bytes(tmp_path / "e2") == snapshot_bytes(tmp_path / "e")  # the other's ensemble is kept
    with pytest.raises(InputError, match="uavrl ensemble"):
        Trainer(_tiny_config().model_copy(update={"ensemble": 2}), ["c-000"], corpus_root, tmp_path / "t")


def test_ctrl_c_checkpoints_and_only_resumes_that_ran_are_recorded(tmp_path, city_root, monkeypatch):
    """Ctrl-C (SIGINT) mid-training: a checkpoint at that step and ``Interrupted`` naming the resume command. A resume
    that dies before its first checkpoint leaves run.json as it was; one that runs is recorded once."""
    monkeypatch.delenv("UAVPLACE_CTRL_C")  # a user's run, not the suite's
    import os
    import signal

    from uavplace.rl.agent.resume import Interrupted

    def press_at(step: int):
        def on_progress(p) -> None:
            if p.step >= step:
                os.kill(os.getpid(), signal.SIGINT)

        return on_progress

    run = tmp_path / "r"
    before = signal.getsignal(signal.SIGINT)  # the default handler, or SIG_IGN in a background job
    with pytest.raises(Interrupted, match=f"Continue with: uavrl train --resume {run}") as stop:
        Trainer(_tiny_config(), ["tiny"], city_root, run, command="uavrl train").run(on_progress=press_at(40))
    last = json.loads((run / "checkpoints" / "last" / "checkpoint.json").read_text())
    assert last["step"] == stop.value.step and 40 <= stop.value.step < 128  # before the first evaluation

    def crash(p) -> None:
        raise RuntimeError("the machine went away")

    with pytest.raises(RuntimeError):
        Trainer(_tiny_config(), ["tiny"], city_root, run, command="uavrl train --resume r").run(resume=True, on_progress=crash)
    assert read_run_json(run).resumed == []
    Trainer(_tiny_config(), ["tiny"], city_root, run, command="uavrl train --resume r").run(resume=True)
    assert read_run_json(run).resumed == [f"uavrl train --resume r (from step {stop.value.step})"]
    assert signal.getsignal(signal.SIGINT) is before  # the handler is put back
    # killed before its first checkpoint (only run.json written): `--resume` starts it over in its folder
    from click.testing import CliRunner

    from uavplace.cli import uavrl

    early = tmp_path / "early"
    Trainer(_tiny_config(), ["tiny"], city_root, early, command="uavrl train").write_run_json()
    res = CliRunner().invoke(uavrl, ["train", "--resume", str(early), "--root", str(city_root), "--quiet"])
    assert res.exit_code == 0, res.output
    assert (early / "checkpoints" / "best.pt").is_file() and read_run_json(early).config == _tiny_config()


def test_a_runs_task_is_its_settings_and_an_earlier_record_reads_alike():
    """``DQNConfig.task`` is the task's settings told apart by ``kind`` (a discriminated union); a run.json written
    before (``"task": "tracking"`` beside ``"tracking": {...}``) reads as the same config, and the settings of one task
    are refused on another."""
    from uavplace.rl.agent.config import DQNConfig, preset_config
    from uavplace.schemas import InputError

    for kind, settings in (("tracking", {"horizon": 24}), ("fleet", {"uavs": 3, "users": 4})):
        new = preset_config("best", task=kind, **{kind: settings})
        doc = new.model_dump(mode="json")
        assert doc["task"]["kind"] == kind and all(doc["task"][k] == v for k, v in settings.items())
        old = {k: v for k, v in doc.items() if k != "task"}
        old |= {"task": kind, kind: {k: v for k, v in doc["task"].items() if k != "kind"}}
        assert DQNConfig.model_validate(old) == new
        with pytest.raises(InputError, match=f"{kind} settings are for --task {kind}"):
            preset_config("best", **{kind: settings})
    placement = preset_config("best")
    assert placement.task.kind == "placement" and placement.n_actions == 4
    earlier = {k: v for k, v in placement.model_dump(mode="json").items() if k != "task"}
    assert DQNConfig.model_validate(earlier | {"tracking": None, "fleet": None}) == placement
    with pytest.raises(ValidationError):
        DQNConfig.model_validate(placement.model_dump(mode="json") | {"task": {"kind": "placement", "horizon": 3}})
    with pytest.raises(InputError, match="unknown task"):
        preset_config("best", task="swarm")


def test_a_first_ctrl_c_ends_the_suite_during_a_training_test(tmp_path):
    """In the suite (``UAVPLACE_CTRL_C=end``, tests/conftest.py) a first Ctrl-C ends ``pytest`` at once, in the middle
    of a training test: the trainer leaves SIGINT as it is, so the next test never starts (with the trainer's handler
    the first test would fail at its next step and the second one would run on, a minute or more). The bound leaves
    room for a loaded machine; alone on 2 cores it ends in a few seconds."""
    import signal
    import subprocess
    import sys
    import time

    from uavplace.rl.agent.resume import interrupts

    before = signal.getsignal(signal.SIGINT)
    with interrupts() as pressed:
        assert signal.getsignal(signal.SIGINT) is before and not pressed()
    victims = [f"tests/test_agent.py::test_short_training_run_learns[{v}]" for v in ("replay", "pqn")]
    inner = tmp_path / "inner"
    command = [sys.executable, "-m", "pytest", "-q", "-n", "0", "-p", "no:cacheprovider", "--basetemp", str(inner), *victims]
    run = subprocess.Popen(command, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.perf_counter() + 300
        while not any(inner.glob("*/run/run.json")) and time.perf_counter() < deadline and run.poll() is None:
            time.sleep(0.5)  # until the first test's training has started
        assert any(inner.glob("*/run/run.json")), "the first test never started training"
        time.sleep(2)
        pressed_at = time.perf_counter()
        run.send_signal(signal.SIGINT)
        output, _ = run.communicate(timeout=120)
        took = time.perf_counter() - pressed_at
    finally:
        run.kill()
    assert took < 20, (took, output[-2000:])
    assert run.returncode == 2 and "KeyboardInterrupt" in output and "passed" not in output, output[-2000:]
