"""What the agents may know: nothing of the user's map beyond the cells they measured.

Each shipped agent plays episodes of the embedded tiny city; then, episode by episode, the user's
SINR, dead-cell mask and the genie's distances are scrambled on every cell the agent never
visited, the user is moved elsewhere in the users table (tests/scramble.py), and the episode is
replayed with the same draws. An agent that reads only its own
measurements moves exactly as before; the genie, which reads the whole map, must change somewhere
(so that the test can fail).
"""

from __future__ import annotations

import numpy as np
import pytest

from tests import scramble
from tests.conftest import REPO
from uavplace.eval.evaluate import default_agents, load_agent
from uavplace.rl.tasks.placement.policies import GeniePolicy
from uavplace.rl.world.maps import MapSet

EPISODES = 12
T_MAX = 60


def test_agents_read_only_what_they_measured(tiny):
    folders = default_agents(REPO / "data" / "agents")
    assert folders, "no shipped agent under data/agents"
    rng = np.random.default_rng(0)
    for folder in folders:
        agent = load_agent(folder, epsilon=0.096, seed=0)
        env = agent.config.env_config(evaluation=True).model_copy(update={"t_max": T_MAX, "rotate": False, "split": None})
        maps = MapSet.load("tiny", env, root=str(tiny))
        episodes = maps.sample_episodes(EPISODES, np.random.default_rng(1))
        same, _ = scramble.replay_placement(maps, agent.policy, episodes, rng)
        assert all(same), f"{folder.name}: moves changed when cells it never visited changed ({same})"
    # The genie on its own draws (not what the agents' replays left of ``rng``) and more episodes: in the tiny city
    # most of its searches are a move or two, and a scramble changes one or two episodes of twelve.
    maps = MapSet.load("tiny", env, root=str(tiny))
    episodes = maps.sample_episodes(4 * EPISODES, np.random.default_rng(1))
    _, changed = scramble.replay_placement(maps, GeniePolicy(), episodes, np.random.default_rng(2))
    assert any(changed), "the genie reads the whole map: scrambling it must change some episode"


def test_report_methods_read_only_what_they_measured(tiny):
    """Every method the report plays beside the agents, but the genie (privileged), receives only the UAV's view
    (``rl.world.view.AgentView``) and moves the same when the user's map is scrambled off its route: the random walk, greedy
    hill-climbing, the map searcher and its ablation."""
    from uavplace.eval.evaluate import ReportConfig, baseline_policies
    from uavplace.rl.tasks.placement.config import EnvConfig
    from uavplace.rl.world.view import AgentView, view_for

    env = EnvConfig(t_max=T_MAX, rotate=False)
    maps = MapSet.load("tiny", env, root=str(tiny))
    from uavplace.rl.config import SearchConfig
    from uavplace.rl.predictor import load_predictor
    from uavplace.rl.tasks.placement.searcher import MapSearchPolicy

    policies = [p for p in baseline_policies(ReportConfig(dataset="tiny"), env) if not getattr(p, "privileged", False)]
    assert {"map searcher", "map searcher, no buildings", "greedy hill-climbing"} <= {p.name for p in policies}
    for planner in ("info", "lookahead"):
        policies.append(MapSearchPolicy(load_predictor(), SearchConfig(planner=planner), name=f"map searcher, {planner}"))
    kriged = SearchConfig(error_share=0.8, kriging="both")  # its own measurements' errors, kriged
    policies.append(MapSearchPolicy(load_predictor(), kriged, name="map searcher, kriging"))
    episodes = maps.episode_list(EPISODES, 1)
    for policy in policies:
        same, _ = scramble.replay_placement(maps, policy, episodes, np.random.default_rng(3))
        assert all(same), f"{policy.name}: moves changed when cells it never visited changed ({same})"
    from uavplace.rl.tasks.placement.env import BatchedEnv

    batch = BatchedEnv(maps, 2)
    batch.reset(0)
    view = view_for(policies[0], batch)
    assert isinstance(view, AgentView) and not any(v is maps or v is batch for v in vars(view).values())


@pytest.mark.slow
def test_searcher_reads_only_what_it_measured_on_a_validation_city(tmp_path):
    """The scramble test on 100 episodes of a validation city with real geometry (etoile-val) and the shipped
    predictor: each episode played again alone with the user's map scrambled off its route moves the same."""
    from uavplace.dataset.build import build_city
    from uavplace.ingest.pipeline import ingest_city
    from uavplace.rl.belief import PredictionCache
    from uavplace.rl.predictor import load_predictor
    from uavplace.rl.tasks.placement.config import EnvConfig
    from uavplace.rl.tasks.placement.rollout import run_episodes
    from uavplace.rl.tasks.placement.searcher import MapSearchPolicy
    from uavplace.schemas.bundle import BuildConfig

    ingest_city(REPO / "data" / "raw" / "etoile-val", tmp_path)
    build_city("etoile-val", BuildConfig(grid_m=4.0, altitude_m=10.0), tmp_path)
    maps = MapSet.load("etoile-val", EnvConfig(t_max=120, rotate=False), root=str(tmp_path))
    policy = MapSearchPolicy(load_predictor(REPO / "data" / "agents" / "searcher" / "unet"),
                             cache=PredictionCache(tmp_path / "predictions"))  # fmt: skip
    episodes = maps.episode_list(100, 0)

    def moved(policy, episodes):  # noqa: ANN001, ANN202 - per episode: did it move otherwise on the scrambled map?
        first = run_episodes(maps, policy, episodes, num_envs=20, record=np.arange(len(episodes)))
        rng, out = np.random.default_rng(4), []
        for k in range(len(episodes)):
            path = first.attrs["paths"][k]
            keep = np.zeros(maps.sinr.shape[1:], bool)
            keep[scramble.to_canvas(maps, int(episodes[k, 0]), path)] = True
            other = scramble.placement(maps, int(episodes[k, 0]), keep, rng)
            again = run_episodes(other, policy, episodes[k : k + 1], num_envs=1, record=np.array([0]))
            out.append(not np.array_equal(again.attrs["paths"][0], path))
        return out

    changed = moved(policy, episodes)
    assert not any(changed), f"moves changed in {sum(changed)} of {len(changed)} episodes"
    assert any(moved(GeniePolicy(), episodes[:40])), "the genie reads the whole map: a scramble must move it somewhere"


def test_planted_cheaters_fail_the_scramble_test(tiny):
    """The scramble test catches a policy that reads where the user is or the user's map where it did not measure
    (tests/cheaters.py, handed the env as the genie is); unprivileged, the same policies cannot run on the view they
    receive; and a policy that writes to its view's public maps changes nothing the env reads: the UAV never enters a
    building, the env's maps are as they were."""
    from tests.cheaters import PlacementMapPeeker, PlacementUserSeeker, PublicWriter
    from uavplace.rl.tasks.placement.config import EnvConfig
    from uavplace.rl.tasks.placement.rollout import run_episodes

    maps = MapSet.load("tiny", EnvConfig(t_max=T_MAX, rotate=False), root=str(tiny))
    episodes = maps.episode_list(EPISODES, 1)
    for cheater in (PlacementUserSeeker(), PlacementMapPeeker()):
        _, changed = scramble.replay_placement(maps, cheater, episodes, np.random.default_rng(5))
        assert any(changed), f"{cheater.name} passed the scramble test"
        cheater.privileged = False
        with pytest.raises(AttributeError):
            run_episodes(maps, cheater, episodes[:2])
    blocked, height = maps.blocked.copy(), maps.height.copy()
    played = run_episodes(maps, PublicWriter(), episodes, record=np.arange(len(episodes)))
    for k in range(len(episodes)):
        y, x = scramble.to_canvas(maps, int(episodes[k, 0]), played.attrs["paths"][k])
        assert not maps.blocked[maps.view_map[int(episodes[k, 0])], y, x].any(), f"episode {k} entered a building"
    assert np.array_equal(maps.blocked, blocked) and np.array_equal(maps.height, height)
