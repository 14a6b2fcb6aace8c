"""`swarmctl bench`'s figures of the search recipe: the scales network's decision against its FLOP limit
and the paper network's, the coordinated teacher's labelling rate on the Chicago Loop grid, and the
search trainer's throughput against its FLOP ceiling. Tiny seconds: the figures' sizes are not judged
here, only that each is measured and the ratios are of the same run's figures."""

from __future__ import annotations

import math

import pytest

from swarmctl.bench import (
    SCALES_WORLD,
    coordinated_labels_per_s,
    ddql_policy,
    decision_figures,
    planner_blocked,
    scales_policy,
    search_training_figures,
)
from swarmctl.policy.qnet import scales_forward_flops


def measured(value: object) -> bool:
    return isinstance(value, float) and math.isfinite(value) and value > 0


def test_the_scales_decision_is_set_against_its_limit_and_the_paper_networks_decision(tmp_path):
    figures = decision_figures(ddql_policy(tmp_path), scales_policy(tmp_path), 0.02)
    for key in (
        "matmul_gflop_per_s",
        "ddql_decision_ms_batch1",
        "scales_decision_ms_per_vehicle_batch1",
        "scales_flop_limit_ms_batch1",
        "scales_decision_over_flop_limit",
        "scales_over_paper_decision",
    ):
        assert measured(figures[key]), key
    assert figures["scales_over_paper_decision"] == pytest.approx(
        figures["scales_decision_ms_per_vehicle_batch1"] / figures["ddql_decision_ms_batch1"]
    )
    # the limit is the scales network's 2.45 MFLOP at the matmul rate of the same rounds
    flops = scales_forward_flops(SCALES_WORLD.window)
    assert figures["scales_flop_limit_ms_batch1"] == pytest.approx(flops / (figures["matmul_gflop_per_s"] * 1e9) * 1e3)
    assert figures["scales_decision_over_flop_limit"] == pytest.approx(
        figures["scales_decision_ms_per_vehicle_batch1"] / figures["scales_flop_limit_ms_batch1"]
    )


def test_the_teacher_labels_vehicle_steps_on_the_chicago_grid():
    assert measured(coordinated_labels_per_s(planner_blocked(), 0.02, episodes=2))


def test_the_search_trainers_throughput_is_set_against_its_ceiling():
    figures = search_training_figures(1, 0.02, parallel_envs=2, curriculum="tiny")
    for key in (
        "search_train_matmul_gflop_per_s",
        "search_train_samples_per_s",
        "search_train_samples_per_wall_s",
        "search_train_flop_ceiling_samples_per_s",
        "search_train_fraction_of_ceiling",
        "search_train_setup_wall_s",
    ):
        assert measured(figures[key]), key
    assert figures["search_train_fraction_of_ceiling"] == pytest.approx(
        figures["search_train_samples_per_s"] / figures["search_train_flop_ceiling_samples_per_s"]
    )
    assert "2 rounds timed" in str(figures["search_train_setting"])
