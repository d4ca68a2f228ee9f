"""requirements-viewer.txt (the viewer extra) is pinned: every package it installs has its exact version in
constraints.txt (so that it installs beside the project's pins, rich's included), and an installed viser is that
version."""

import importlib.metadata

import pytest

from test_gpu_install import constraints
from test_gpu_install import resolved_versions
from test_gpu_install import skip_unless_indexed


def test_the_viewer_extra_resolves_to_constrained_versions_only(tmp_path):
  skip_unless_indexed('viser')
  resolved = resolved_versions(tmp_path, 'requirements-viewer.txt')
  pins = constraints()
  assert 'viser' in resolved and {n: v for n, v in resolved.items() if pins.get(n) != v} == {}


def test_an_installed_viser_is_the_pinned_one():
  try:
    installed = importlib.metadata.version('viser')
  except importlib.metadata.PackageNotFoundError:
    pytest.skip('the viewer extra is not installed (pip install -r requirements-viewer.txt)')
  assert installed == constraints()['viser']
