"""requirements-gpu.txt (the README's GPU install) resolves against constraints.txt: a pip dry run against the
package index, as a CPU machine can check it.

pip 25.3 or newer reads each wheel's metadata by HTTP range requests (`--use-feature=fast-deps`; 13 s here), so
the check runs everywhere, CI included: it is the only one that the GPU pins still resolve. Older pip reads every
wheel whole where the index serves no separate metadata files (PEP 658), as this project's machine's does: about
1.6 GB of CUDA libraries (pip 23.2: 48-72 s here), so then it runs outside CI only (CI=true skips it, saying so).
It also skips, saying why, where the index cannot be reached or jax publishes no CUDA wheels for the platform.
"""

import importlib.metadata
import json
import os
import platform
import re
import subprocess
import sys

import pytest

from test_checkpoints import ROOT

PIP = [sys.executable, '-m', 'pip']
NETWORK = ['--timeout', '20', '--retries', '1']  # An unreachable index fails in seconds, not minutes.
RANGE_READS_SINCE = (25, 3)  # The first pip seen to resolve with fast-deps without downloading the wheels.


def constraints() -> dict:
  """{normalized name: version} of constraints.txt."""
  pins = re.findall(r'^([A-Za-z0-9_.-]+)==(\S+)', (ROOT / 'constraints.txt').read_text(), re.M)
  return {normalized(name): version for name, version in pins}


def normalized(name: str) -> str:
  return re.sub(r'[-_.]+', '-', name).lower()


def metadata_options() -> list:
  """pip's options that read metadata without whole wheels (none for an older pip; then skipped in CI)."""
  version = tuple(int(part) for part in re.findall(r'\d+', importlib.metadata.version('pip'))[:2])
  if version >= RANGE_READS_SINCE:
    return ['--use-feature=fast-deps']
  if os.environ.get('CI', '').lower() in ('1', 'true', 'yes'):
    pytest.skip(f'pip {importlib.metadata.version("pip")} would download about 1.6 GB of CUDA wheels to read their '
                'metadata where the index serves none; CI runs this check with pip 25.3 or newer only')
  return []


def _skip_unless_resolvable():
  if sys.platform != 'linux' or platform.machine() not in ('x86_64', 'aarch64'):
    pytest.skip(f'jax publishes CUDA wheels for Linux x86_64 and aarch64 only, not {sys.platform} '
                f'{platform.machine()}')
  skip_unless_indexed('jax-cuda12-plugin')


def skip_unless_indexed(package: str) -> None:
  """Skips the test when pip cannot reach the package index (asked for package's versions)."""
  probe = subprocess.run(PIP + ['index', 'versions', package] + NETWORK, capture_output=True, text=True, timeout=120,
                         check=False)
  if probe.returncode != 0:
    reason = (probe.stderr.strip().splitlines() or ['no message'])[-1]
    pytest.skip(f'the package index cannot be reached (pip index versions {package}: {reason})')


def resolved_versions(report_dir, requirements: str, options=()) -> dict:
  """{normalized name: version} that pip resolves for a requirements file of the repository, installing nothing."""
  report = report_dir / 'report.json'
  command = PIP + ['install', '--dry-run', '--ignore-installed', '--quiet', '--report', str(report), '-r',
                   requirements] + list(options) + NETWORK
  proc = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=600, check=False)
  assert proc.returncode == 0, proc.stderr[-3000:]
  return {normalized(item['metadata']['name']): item['metadata']['version']
          for item in json.loads(report.read_text())['install']}


@pytest.mark.slow
def test_the_gpu_requirements_resolve_to_the_constrained_jax_with_its_cuda_plugin(tmp_path):
  _skip_unless_resolvable()
  resolved = resolved_versions(tmp_path, 'requirements-gpu.txt', metadata_options())
  pins = constraints()
  jax_version = pins['jax']
  for name in ('jax', 'jaxlib', 'jax-cuda12-plugin', 'jax-cuda12-pjrt'):
    assert resolved.get(name) == jax_version, (name, resolved.get(name))
  assert 'nvidia-cudnn-cu12' in resolved and 'nvidia-cublas-cu12' in resolved  # CUDA comes as wheels.
  differing = {name: (version, resolved[name]) for name, version in pins.items()
               if name in resolved and resolved[name] != version}
  assert not differing  # Every package the CPU install pins keeps its version.
