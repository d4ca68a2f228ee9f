"""requirements-cluster.txt (the Ray extra) is pinned: every package it installs beyond requirements.txt has its exact
version in constraints.txt, and an installed Ray is that version."""

import importlib.metadata

import pytest

from test_gpu_install import _skip_unless_resolvable
from test_gpu_install import constraints
from test_gpu_install import resolved_versions


def test_the_cluster_extra_resolves_to_constrained_versions_only(tmp_path):
  _skip_unless_resolvable()
  resolved = resolved_versions(tmp_path, 'requirements-cluster.txt')
  pins = constraints()
  assert 'ray' in resolved and {n: v for n, v in resolved.items() if pins.get(n) != v} == {}


def test_an_installed_ray_is_the_pinned_one():
  try:
    installed = importlib.metadata.version('ray')
  except importlib.metadata.PackageNotFoundError:
    pytest.skip('the cluster extra is not installed (pip install -r requirements-cluster.txt)')
  assert installed == constraints()['ray']
