"""Tests of granflow.campaign.warm (the compile-warm job beside the base preparation)."""

from __future__ import annotations

import json
from pathlib import Path

import yaml

from granflow.campaign.commands import _merge
from granflow.campaign.warm import warm_engine, warm_runs

REPO = Path(__file__).resolve().parents[1]


def merged(*names):
    cfg: dict = {}
    for n in names:
        with open(REPO / "config" / n) as fh:
            _merge(cfg, yaml.safe_load(fh))
    return cfg


def test_one_warm_run_per_kind_and_law_the_thinnest():
    cfg = merged("config.yaml")
    runs = warm_runs(cfg)
    kinds = [(p.kind, p.law) for p in runs]
    assert len(kinds) == len(set(kinds))
    from granflow.campaign.grid import expand_runs

    grid = expand_runs(cfg)
    assert set(kinds) == {(p.kind, p.law) for p in grid}
    for p in runs:
        assert p.H == min(q.H for q in grid if (q.kind, q.law) == (p.kind, p.law))


def test_warm_engine_keeps_only_its_record(tmp_path):
    cfg = merged("config.yaml", "test-tiny.yaml")
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    out = tmp_path / "logs" / "warm_engine.json"
    out.parent.mkdir()
    rec = warm_engine(cfg, out, scratch=scratch)
    assert json.loads(out.read_text()) == rec
    assert [r["run"] for r in rec["runs"]] == [p.path for p in warm_runs(cfg)]
    assert list(scratch.iterdir()) == []  # the tiny runs' files are removed
