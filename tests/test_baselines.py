"""Rule-based baselines (Policy-MA, Policy-OP): hand-computed terms, configs, rollouts."""

from __future__ import annotations

import dataclasses
import math

import pytest
from helpers import first_fast
import torch
from tensordict.nn import TensorDictModuleBase

from flock_torchrl import FlockingEnv, make_policy
from flock_torchrl.config import ConfigError, compose_world
from flock_torchrl.policies.baselines import OlfatiSaberParams, controller_params, make_baseline
from flock_torchrl.policies.baselines import olfati_saber as os_
from flock_torchrl.policies.baselines import vasarhelyi as va
from flock_torchrl.policies.baselines.sensing import nearest_hits, neighbour_view
from flock_torchrl.policies.registry import policy_config_of
from flock_torchrl.run.rollout import evaluate
from flock_torchrl.world.geometry import Obstacles
from flock_torchrl.world.laser import laser_scan

SCENARIOS = ("train", "s1", "s2", "s3", "s4", "s5")
BASELINES = ("policy_ma", "policy_op")


def yaml_params(name):
    """The controller's parameters as conf/policy/<name>.yaml composes them."""
    return controller_params(policy_config_of(name, "literal")[0])


def baseline_env(name, scenario, num_envs, seed, **kwargs):
    return FlockingEnv(scenario, num_envs=num_envs, seed=seed, reading="literal", policy_id=name,
                       extras=("physics", "laser"), **kwargs)


def t(*values):
    return torch.tensor(values, dtype=torch.float32)


# ----------------------------------------------------------------------------- Olfati-Saber helpers


def test_sigma_norm_and_gradient_values():
    # |z| = 5, eps = 0.1: (sqrt(1 + 2.5) - 1) / 0.1
    assert os_.sigma_norm(t(3.0, 4.0), 0.1).item() == pytest.approx((math.sqrt(3.5) - 1) / 0.1, rel=1e-6)
    assert os_.sigma_norm(t(0.0, 0.0), 0.1).item() == 0.0
    assert torch.allclose(os_.sigma_gradient(t(3.0, 4.0), 0.1), t(3.0, 4.0) / math.sqrt(3.5))
    assert torch.allclose(os_.sigma_1(t(0.0, 1.0, -2.0)), t(0.0, 1 / math.sqrt(2), -2 / math.sqrt(5)))


def test_bump_values():
    z = t(0.0, 0.1, 0.2, 0.6, 1.0, 1.5)
    expected = t(1.0, 1.0, 1.0, 0.5, 0.0, 0.0)  # h = 0.2: cos(pi * 0.4 / 0.8) = 0 at z = 0.6
    assert torch.allclose(os_.bump(z, 0.2), expected, atol=1e-6)


def test_phi_alpha_sign_and_zero_at_desired_distance():
    eps, d, r = 0.1, 3.0, 3.6
    d_a, r_a = os_.sigma_norm_of_length(d, eps), os_.sigma_norm_of_length(r, eps)
    z = os_.sigma_norm_of_length(t(1.0, d, 3.3, 4.0), eps)
    phi = os_.phi_alpha(z, r_a, d_a, 0.2, 5.0, 5.0)
    assert phi[0] < 0 and phi[1].abs() < 1e-6 and phi[2] > 0 and phi[3] == 0
    # uneven a < b keeps phi(0) = 0 (c = |a - b| / sqrt(4ab))
    assert os_.action_phi(t(0.0), 2.0, 5.0).abs().item() < 1e-6


def test_two_alpha_agents_at_desired_distance_feel_no_force():
    p = yaml_params("policy_ma")
    kw = dict(eps=p.eps, r=p.r, d=p.d, h=p.h_alpha, a=p.a, b=p.b)
    for gap, sign in ((p.d, 0), (1.0, -1), (0.5 * (p.d + p.r), 1)):
        offset = torch.zeros(1, 2, 2, 2)
        offset[0, 0, 1] = t(gap, 0.0)   # q_1 - q_0
        offset[0, 1, 0] = t(-gap, 0.0)
        visible = ~torch.eye(2, dtype=torch.bool)[None]
        gradient, consensus = os_.alpha_terms(offset, torch.zeros_like(offset), visible, **kw)
        assert torch.allclose(consensus, torch.zeros(1, 2, 2))
        if sign == 0:
            assert torch.allclose(gradient, torch.zeros(1, 2, 2), atol=1e-5)  # float32
        else:  # too close: agent 0 pushed to -x; too far (inside r): pulled to +x
            assert torch.sign(gradient[0, 0, 0]).item() == sign and gradient[0, 0, 1] == 0
            assert torch.allclose(gradient[0, 0], -gradient[0, 1])


def test_alpha_consensus_pulls_towards_neighbour_velocity():
    offset = torch.zeros(1, 2, 2, 2)
    offset[0, 0, 1], offset[0, 1, 0] = t(3.0, 0.0), t(-3.0, 0.0)
    rel = torch.zeros(1, 2, 2, 2)
    rel[0, 0, 1], rel[0, 1, 0] = t(0.0, 1.0), t(0.0, -1.0)
    visible = torch.tensor([[[False, True], [False, False]]])  # 0 sees 1, 1 does not see 0
    _, consensus = os_.alpha_terms(offset, rel, visible, eps=0.1, r=3.6, d=3.0, h=0.2, a=5.0, b=5.0)
    assert consensus[0, 0, 1] > 0 and consensus[0, 0, 0] == 0
    assert torch.equal(consensus[0, 1], torch.zeros(2))  # what a UAV cannot see does not act on it


def test_phi_beta_is_repulsive_and_vanishes_beyond_d_beta():
    d_b = os_.sigma_norm_of_length(3.0, 0.1)
    z = os_.sigma_norm_of_length(t(0.5, 1.5, 2.9, 3.0, 4.0), 0.1)
    phi = os_.phi_beta(z, d_b, 0.9)
    assert (phi[:3] < 0).all() and (phi[3:] == 0).all()
    assert phi[0] < phi[1] < phi[2]  # stronger nearer


def test_beta_agent_projection_on_a_wall():
    # wall y = 0 through (5, 0), normal +y; agent at (1, 2) moving (1, -1)
    qh, ph = os_.beta_agent_wall(t(1.0, 2.0), t(1.0, -1.0), t(0.0, 1.0), t(5.0, 0.0))
    assert torch.allclose(qh, t(1.0, 0.0)) and torch.allclose(ph, t(1.0, 0.0))


def test_beta_agent_projection_on_a_circle():
    # centre (0, 0), R = 1, agent at (2, 0) moving (1, 1): mu = 0.5, qh = (1, 0), ph = 0.5 (0, 1)
    qh, ph = os_.beta_agent_circle(t(2.0, 0.0), t(1.0, 1.0), t(0.0, 0.0), 1.0)
    assert torch.allclose(qh, t(1.0, 0.0)) and torch.allclose(ph, t(0.0, 0.5))


def _scan(position, heading, circles=(), rectangles=()):
    obstacles = Obstacles(torch.tensor(circles, dtype=torch.float32).reshape(1, -1, 3),
                          torch.tensor(rectangles, dtype=torch.float32).reshape(1, -1, 4))
    beams, index = laser_scan(torch.tensor([[position]], dtype=torch.float32), torch.tensor([[heading]]),
                              obstacles, 36, 10.0)
    return beams, index, obstacles.count


def test_laser_beta_agents_match_the_exact_projections():
    # circle centre (5, 0), R = 2 and a wall (rectangle face x = -4) seen from the origin
    beams, index, m = _scan((0.0, 0.0), 0.0, circles=[(5.0, 0.0, 2.0)], rectangles=[(-5.0, 0.0, 2.0, 20.0)])
    hits = nearest_hits(beams, index, torch.zeros(1, 1), m)
    assert hits.seen.all()
    velocity = t(1.0, 1.0).reshape(1, 1, 2)
    offset, ph = os_.beta_agents_from_scan(hits.offset, hits.normal, velocity)
    qh_c, ph_c = os_.beta_agent_circle(t(0.0, 0.0), t(1.0, 1.0), t(5.0, 0.0), 2.0)
    qh_w, ph_w = os_.beta_agent_wall(t(0.0, 0.0), t(1.0, 1.0), t(1.0, 0.0), t(-4.0, 0.0))
    assert torch.allclose(offset[0, 0, 0], qh_c, atol=1e-5) and torch.allclose(offset[0, 0, 1], qh_w, atol=1e-5)
    assert torch.allclose(ph[0, 0, 1], ph_w, atol=1e-5)                      # wall: exact
    assert torch.allclose(ph[0, 0, 0] * (2.0 / 5.0), ph_c, atol=1e-5)       # circle: up to mu = R / |q - y|
    # each obstacle's gradient pushes the UAV away from it (circle at +x, wall at -x)
    for k, sign in ((0, -1.0), (1, 1.0)):
        only_k = torch.zeros_like(hits.seen)
        only_k[..., k] = True
        grad, _ = os_.beta_terms(offset, ph, velocity, only_k, eps=0.1, d_beta=5.0, r_beta=6.0, h=0.9)
        assert torch.sign(grad[0, 0, 0]).item() == sign and grad[0, 0, 1].abs() < 1e-5


def test_nearest_hits_counts_each_obstacle_once():
    beams, index, m = _scan((0.0, 0.0), 0.3, rectangles=[(0.0, 4.0, 30.0, 2.0), (0.0, -8.0, 2.0, 2.0)])
    assert (index == 0).sum() > 5  # the long wall is hit by many beams ...
    hits = nearest_hits(beams, index, torch.full((1, 1), 0.3), m)
    assert hits.distance.shape == (1, 1, 2) and hits.seen.all()
    assert hits.distance[0, 0, 0].item() == pytest.approx(3.0, abs=0.05)  # ... but is one beta/shill agent
    assert torch.allclose(hits.normal[0, 0, 0], t(0.0, -1.0), atol=0.1)   # pointing from the wall to the UAV
    assert hits.distance[0, 0, 1].item() == pytest.approx(7.0, abs=0.1)


def test_gamma_term_points_at_the_goal():
    to_goal = t(30.0, -40.0).reshape(1, 1, 2)
    u = os_.gamma_term(to_goal, torch.zeros(1, 1, 2), 2.0, 1.0)
    assert torch.allclose(u[0, 0], 2.0 * t(30.0, -40.0) / math.sqrt(1 + 2500))
    # at cruise speed c1 / c2 towards a far goal the feedback vanishes (nearly)
    u = os_.gamma_term(to_goal, (2.0 * t(0.6, -0.8)).reshape(1, 1, 2), 2.0, 1.0)
    assert u.norm() < 1e-3


def test_acceleration_to_command_realises_u_and_caps_norm():
    v = t(1.0, 0.0).reshape(1, 1, 2)
    assert torch.allclose(os_.acceleration_to_command(v, t(0.5, 0.5).reshape(1, 1, 2), 1.0, 3.0)[0, 0], t(1.5, 0.5))
    big = os_.acceleration_to_command(v, t(10.0, 10.0).reshape(1, 1, 2), 1.0, 3.0)
    assert big.norm().item() == pytest.approx(3.0, rel=1e-5)


# ----------------------------------------------------------------------------- Vasarhelyi terms


def test_braking_curve_values():
    a, p = 3.0, 3.0  # linear below a / p^2 = 1/3
    r = t(-1.0, 0.0, 0.2, 1.0 / 3.0, 2.0)
    expected = t(0.0, 0.0, 0.6, 1.0, math.sqrt(12.0 - 1.0))
    assert torch.allclose(va.braking_curve(r, a, p), expected, atol=1e-5)


def _pair(gap, v0=(0.0, 0.0), v1=(0.0, 0.0)):
    offset = torch.zeros(1, 2, 2, 2)
    offset[0, 0, 1], offset[0, 1, 0] = t(gap, 0.0), t(-gap, 0.0)
    distance = offset.norm(dim=-1)
    velocity = torch.stack((t(*v0), t(*v1)))[None]
    rel = velocity[:, None, :, :] - velocity[:, :, None, :]
    return offset, distance, rel, ~torch.eye(2, dtype=torch.bool)[None]


def test_repulsion_is_linear_and_short_range():
    offset, distance, _, visible = _pair(1.0)
    rep = va.repulsion(offset, distance, visible, p_rep=0.8, r0_rep=3.0)
    assert torch.allclose(rep[0], torch.stack((t(-1.6, 0.0), t(1.6, 0.0))))
    offset, distance, _, visible = _pair(3.5)
    assert torch.equal(va.repulsion(offset, distance, visible, p_rep=0.8, r0_rep=3.0), torch.zeros(1, 2, 2))


def test_friction_vanishes_below_its_slack():
    kw = dict(c_frict=0.3, v_frict=0.5, r0_frict=4.0, a_frict=4.16, p_frict=3.2)
    _, distance, rel, visible = _pair(2.0, v0=(2.0, 0.0), v1=(2.4, 0.0))   # |v_ij| = 0.4 < 0.5
    assert torch.equal(va.friction(rel, distance, visible, **kw), torch.zeros(1, 2, 2))
    _, distance, rel, visible = _pair(2.0, v0=(2.0, 0.0), v1=(3.0, 0.0))   # |v_ij| = 1.0 > 0.5
    f = va.friction(rel, distance, visible, **kw)
    assert torch.allclose(f[0, 0], t(0.3 * 0.5, 0.0)) and torch.allclose(f[0, 1], t(-0.3 * 0.5, 0.0))
    # beyond r0_frict the braking curve tolerates more: D(1.0) = sqrt(2 a - a^2 / p^2) > 1
    _, distance, rel, visible = _pair(5.0, v0=(2.0, 0.0), v1=(3.0, 0.0))
    assert torch.equal(va.friction(rel, distance, visible, **kw), torch.zeros(1, 2, 2))


def test_shill_agent_points_away_from_the_obstacle_surface():
    normal = t(0.0, 1.0).reshape(1, 1, 1, 2)       # surface below the UAV
    seen = torch.ones(1, 1, 1, dtype=torch.bool)
    kw = dict(v_shill=7.5, r0_shill=0.5, a_shill=3.02, p_shill=3.55)
    at_rest = va.shill(t(1.0).reshape(1, 1, 1), normal, seen, torch.zeros(1, 1, 2), **kw)
    assert at_rest[0, 0, 0].abs() < 1e-6 and at_rest[0, 0, 1] > 0
    diving = va.shill(t(1.0).reshape(1, 1, 1), normal, seen, t(0.0, -2.0).reshape(1, 1, 2), **kw)
    assert diving[0, 0, 1] > at_rest[0, 0, 1]       # heading at the surface brakes harder
    # the shill acts while D(r - r0_shill) < v_shill, i.e. up to r0 + (v_shill^2 + a^2/p^2) / 2a
    reach = 0.5 + (5.0**2 + 3.02**2 / 3.55**2) / (2 * 3.02)
    near = va.shill(t(reach - 0.1).reshape(1, 1, 1), normal, seen, torch.zeros(1, 1, 2), **{**kw, "v_shill": 5.0})
    far = va.shill(t(reach + 0.1).reshape(1, 1, 1), normal, seen, torch.zeros(1, 1, 2), **{**kw, "v_shill": 5.0})
    assert near[0, 0, 1] > 0 and torch.equal(far, torch.zeros(1, 1, 2))


def test_self_propulsion_points_at_the_goal():
    v = va.self_propulsion(t(0.0, -10.0).reshape(1, 1, 2), 3.0)
    assert torch.allclose(v[0, 0], t(0.0, -3.0))


def test_neighbours_outside_the_field_of_view_are_ignored():
    # UAV 0 at the origin heading +x; UAV 1 one metre behind it: 0 cannot see 1, 1 sees 0
    position = torch.tensor([[[0.0, 0.0], [-1.0, 0.0]]])
    view = neighbour_view(position, torch.zeros(1, 2, 2), torch.zeros(1, 2), 5.0, math.pi / 4)
    assert view.visible.tolist() == [[[False, False], [True, False]]]
    rep = va.repulsion(view.offset, view.distance, view.visible, p_rep=0.8, r0_rep=3.0)
    assert torch.equal(rep[0, 0], torch.zeros(2)) and rep[0, 1, 0] < 0


# ----------------------------------------------------------------------------- configs


@pytest.mark.parametrize("name", BASELINES)
def test_yaml_documents_every_parameter(name):
    policy, scenario = policy_config_of(name, "literal")
    params = controller_params(policy)
    assert set(policy.params) == {f.name for f in dataclasses.fields(params)}
    assert policy.kind == "rule" and scenario["action_mode"] == "velocity" and scenario["instinct"] is False
    assert scenario["fov"] == pytest.approx(math.pi / 2)


def test_command_line_params_reach_the_controller():
    cfg = compose_world("s1", "literal", "policy_op", ["policy.params.v_flock=2.0"])
    from flock_torchrl.config import PolicyConfig

    env = baseline_env("policy_op", "s1", 1, 0)
    policy = make_baseline(PolicyConfig.from_config(cfg.policy), env.cfg)
    assert isinstance(policy, TensorDictModuleBase) and policy.params.v_flock == 2.0
    assert policy.env_cfg.action_mode == "velocity" and policy.env_cfg.half_fov == pytest.approx(math.pi / 4)
    assert ("agents", "action") in policy.out_keys and ("agents", "scan_obstacle") in policy.in_keys


def test_bad_params_fail_naming_the_field():
    policy = policy_config_of("policy_ma", "literal")[0]
    with pytest.raises(ConfigError, match="c1_gama"):
        controller_params(dataclasses.replace(policy, params={**policy.params, "c1_gama": 1.0}))
    with pytest.raises(ConfigError, match="c1_gamma"):  # a missing one too: every value lives in the YAML
        controller_params(dataclasses.replace(policy, params={k: v for k, v in policy.params.items()
                                                              if k != "c1_gamma"}))
    op = policy_config_of("policy_op", "literal")[0]
    with pytest.raises(ConfigError, match="v_flock"):
        controller_params(dataclasses.replace(op, params={**op.params, "v_flock": -1.0}))
    with pytest.raises(ConfigError, match="'a'|params.a"):
        OlfatiSaberParams(**{**policy.params, "a": 6.0, "b": 5.0})
    with pytest.raises(ConfigError, match="h_beta"):
        controller_params(dataclasses.replace(policy, params={**policy.params, "h_beta": 1.0}))
    with pytest.raises(ConfigError, match="kind"):
        make_baseline(policy_config_of("policy3_g")[0], FlockingEnv("s1", num_envs=1).cfg)
    with pytest.raises(ConfigError, match="action_mode"):
        make_baseline(op, FlockingEnv("s1", num_envs=1).cfg)


# ----------------------------------------------------------------------------- in the env


@pytest.mark.parametrize("scenario", first_fast(SCENARIOS))
def test_rollout_in_every_scenario_has_no_nan(scenario):
    for name in BASELINES:
        env = baseline_env(name, scenario, num_envs=3, seed=7)
        td = env.rollout(40, policy=make_policy(name, env), break_when_any_done=False)
        action = td["agents", "action"]
        assert action.shape == (3, 40, env.n_agents, 2)
        assert torch.isfinite(action).all() and torch.isfinite(td["next", "agents", "position"]).all()
        assert (action.norm(dim=-1) <= env.cfg.v_max + 1e-4).all()


@pytest.mark.parametrize("name", BASELINES)
def test_every_s1_episode_reaches_the_goal(name):
    result = evaluate(name, "s1", "literal", n_episodes=16, seed=11)
    metrics = result.episodes
    assert metrics["success"].all()
    assert (metrics["steps"].float() * 0.2 - metrics["t_goal"]).abs().max() < 1e-3  # first done recorded
    assert result.rate("success").rate == 1.0 and 2.0 < result.cell("speed").mean <= 3.0


def test_policy_runs_on_the_inputs_device():
    device = "cuda" if torch.cuda.is_available() else "cpu"
    env = baseline_env("policy_ma", "s5", num_envs=2, seed=0, device=device)
    for name in BASELINES:
        td = make_policy(name, env)(env.reset())
        assert td["agents", "action"].device.type == torch.device(device).type


@pytest.mark.slow
def test_tuning_walks_the_grid_with_tied_parameters_and_picks_a_grid_point():
    """report/tuning.py (make tune-baselines) in the fast tier: Policy-MA's grid is 3 x 3 points,
    r kept at 1.2 d and r_beta at 1.2 d_beta (docs/baselines.md); a short tuning run scores
    each point once and chooses one of them."""
    from flock_torchrl.report.tuning import candidates, tune

    points = list(candidates("policy_ma"))
    assert len(points) == 9
    assert points[0] == {"d": 3.0, "d_beta": 2.0, "r": 3.6, "r_beta": 2.4}  # 1.2 * 3.0, 1.2 * 2.0
    chosen, rows = tune("policy_ma", "literal", episodes=1, seed=0, max_steps=10, log=lambda message: None)
    assert len(rows) == 9 and all(0.0 <= row["score"] <= 1.0 for row in rows)
    assert chosen in points  # tied parameters included
