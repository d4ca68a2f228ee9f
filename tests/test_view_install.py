"""requirements-viewer.txt (the viewer extra) is pinned: every package it installs has its exact version in
constraints.txt (so that it installs beside the project's pins, rich's included), and an installed viser is that
version."""

import importlib.metadata
import json
import subprocess

import pytest

from test_gpu_install import NETWORK
from test_gpu_install import PIP
from test_gpu_install import ROOT
from test_gpu_install import constraints
from test_gpu_install import normalized


def test_the_viewer_extra_resolves_to_constrained_versions_only(tmp_path):
  probe = subprocess.run(PIP + ['index', 'versions', 'viser'] + NETWORK, capture_output=True, text=True, timeout=120,
                         check=False)
  if probe.returncode != 0:
    pytest.skip('the package index cannot be reached (pip index versions viser: '
                f'{(probe.stderr.strip().splitlines() or ["no message"])[-1]})')
  report = tmp_path / 'report.json'
  proc = subprocess.run(PIP + ['install', '--dry-run', '--ignore-installed', '--quiet', '--report', str(report), '-r',
                               'requirements-viewer.txt'] + NETWORK, cwd=ROOT, capture_output=True, text=True,
                        timeout=600, check=False)
  assert proc.returncode == 0, proc.stderr[-3000:]
  resolved = {normalized(item['metadata']['name']): item['metadata']['version']
              for item in json.loads(report.read_text())['install']}
  pins = constraints()
  assert 'viser' in resolved and {n: v for n, v in resolved.items() if pins.get(n) != v} == {}


def test_an_installed_viser_is_the_pinned_one():
  try:
    installed = importlib.metadata.version('viser')
  except importlib.metadata.PackageNotFoundError:
    pytest.skip('the viewer extra is not installed (pip install -r requirements-viewer.txt)')
  assert installed == constraints()['viser']
