"""Tests of tools/tables.py on synthetic metrics.json files: the numbers in the tables and the incomplete sets."""

import csv
import json
import pathlib
import subprocess
import sys

import pytest

from internal.evaluation import results
from tools import tables

REPO = pathlib.Path(__file__).resolve().parents[1]
LLFF = results.EXPECTED_SCENES['llff']
DTU = results.EXPECTED_SCENES['dtu']


def _llff_values(i):
  """Per-scene metric values of LLFF scene number i."""
  return {'psnr': 19. + 0.2 * i, 'ssim': 0.6 + 0.02 * i, 'lpips': 0.3 - 0.02 * i, 'avg_error': 0.1 + 0.002 * i}


def _dtu_values(i):
  """Per-scene metric values (full and masked) of DTU scan number i."""
  full = {'psnr': 15. + 0.1 * i, 'ssim': 0.5 + 0.02 * i, 'lpips': 0.4, 'avg_error': 0.2 - 0.002 * i}
  return {**full, **{f'{k}_masked': v + 1. for k, v in full.items()}}


def _write(root, dataset, scene, views, method, values, step=1000, complete=True, seeds=None):
  """Writes a one-image metrics.json under root/<method>/<dataset><views>/<scene>/[seeds]/ and returns its path."""
  run = root / method / f'{dataset}{views}' / scene / f'step{step}' / str(seeds)
  run.mkdir(parents=True)
  record = results.make_record(dataset, scene, views, method, step, [{'id': 0, **values}], complete)
  if seeds is not None:
    record['seeds'] = seeds
  results.write_record(run / results.METRICS_FILENAME, record)
  return run / results.METRICS_FILENAME


def _read_csv(path):
  """CSV rows as dicts keyed by the header."""
  with open(path, newline='') as f:
    return list(csv.DictReader(f))


def _by(rows, column):
  """Rows indexed by one column."""
  return {row[column]: row for row in rows}


@pytest.fixture(name='runs')
def fixture_runs(tmp_path):
  """LLFF: freenerf complete (3 views), mipnerf without trex; DTU: freenerf with scan8 incomplete + scan24."""
  root = tmp_path / 'runs'
  for i, scene in enumerate(LLFF):
    _write(root, 'llff', scene, 3, 'freenerf', _llff_values(i))
    if scene != 'trex':
      _write(root, 'llff', scene, 3, 'mipnerf', _llff_values(i + 1))
  _write(root, 'llff', 'fern', 3, 'freenerf', _llff_values(50), step=500)   # Older run: ignored.
  for i, scene in enumerate(DTU):
    _write(root, 'dtu', scene, 3, 'freenerf', _dtu_values(i), complete=scene != 'scan8')
  _write(root, 'dtu', 'scan24', 3, 'freenerf', _dtu_values(100))
  return root


def test_make_record_means_over_images():
  record = results.make_record('llff', 'fern', 3, 'freenerf', 7,
                               [{'id': 0, 'psnr': 20., 'lpips': None}, {'id': 8, 'psnr': 23., 'lpips': None}], True)
  assert record['means'] == {'psnr': 21.5, 'lpips': None}
  with pytest.raises(ValueError, match='n_input_views'):
    results.make_record('llff', 'fern', '3', 'freenerf', 7, [], True)


def test_complete_llff_means_and_incomplete_method(runs, tmp_path, capsys):
  out = tmp_path / 'out'
  assert tables.main([str(runs), '--out', str(out)]) == 0
  summary = _by(_read_csv(out / 'llff_summary.csv'), 'method')
  assert float(summary['freenerf']['3 views PSNR']) == pytest.approx(19. + 0.2 * 3.5, abs=1e-6)
  assert float(summary['freenerf']['3 views SSIM']) == pytest.approx(0.67, abs=1e-6)
  assert float(summary['freenerf']['3 views LPIPS']) == pytest.approx(0.23, abs=1e-6)
  assert float(summary['freenerf']['3 views Avg']) == pytest.approx(0.107, abs=1e-6)
  assert summary['mipnerf']['3 views PSNR'] == ''                      # trex missing: no mean.
  per_scene = _by(_read_csv(out / 'llff_freenerf_3views.csv'), 'scene')
  assert per_scene['fern']['step'] == '1000' and float(per_scene['fern']['PSNR']) == pytest.approx(19.)
  assert float(per_scene['mean']['PSNR']) == pytest.approx(19.7, abs=1e-6)
  mip = _by(_read_csv(out / 'llff_mipnerf_3views.csv'), 'scene')
  assert mip['trex']['note'] == 'missing' and mip['mean']['PSNR'] == ''
  err = capsys.readouterr().err
  assert 'LLFF mipnerf 3 views: mean left empty (missing scenes: trex)' in err
  assert 'ignoring step 500' in err
  markdown = (out / 'llff.md').read_text()
  assert '| freenerf | 19.70 | 0.670 | 0.230 | 0.107 |' in markdown
  assert '| mipnerf | – | – | – | – |' in markdown


def test_dtu_incomplete_run_and_extra_scene(runs, tmp_path, capsys):
  out = tmp_path / 'out'
  tables.main([str(runs), '--out', str(out)])
  per_scene = _by(_read_csv(out / 'dtu_freenerf_3views.csv'), 'scene')
  assert per_scene['scan8']['note'] == 'incomplete' and per_scene['mean']['object PSNR'] == ''
  assert per_scene['scan24']['note'] == 'not a protocol scene'
  assert float(per_scene['scan24']['object PSNR']) == pytest.approx(26.)
  err = capsys.readouterr().err
  assert 'incomplete runs (complete=false): scan8' in err and 'scan24 is not one of' in err


def test_allow_incomplete_marks_partial_means(runs, tmp_path):
  out = tmp_path / 'out'
  tables.main([str(runs), '--out', str(out), '--allow-incomplete'])
  summary = _by(_read_csv(out / 'llff_summary.csv'), 'method')
  assert summary['mipnerf']['3 views PSNR'] == f'{19. + 0.2 * 4:.6f}*'   # Scenes 1..7 of _llff_values.
  assert summary['freenerf']['3 views PSNR'] == f'{19.7:.6f}'              # Complete: no mark.
  full = _by(_read_csv(out / 'dtu_summary_full.csv'), 'method')['freenerf']
  obj = _by(_read_csv(out / 'dtu_summary_object.csv'), 'method')['freenerf']
  assert full['3 views PSNR'] == f'{15. + 0.1 * 7:.6f}*'                # All 15 scans (scan8 included), no scan24.
  assert obj['3 views PSNR'] == f'{16. + 0.1 * 7:.6f}*'
  assert float(obj['3 views SSIM'].rstrip('*')) == pytest.approx(1.5 + 0.02 * 7)
  markdown = (out / 'dtu.md').read_text()
  assert '| freenerf | 16.70* |' in markdown and '- DTU freenerf 3 views: * = mean over what exists only (incomplete runs' in markdown


def test_missing_lpips_leaves_lpips_and_avg_empty(tmp_path, capsys):
  root = tmp_path / 'runs'
  for i, scene in enumerate(LLFF):
    _write(root, 'llff', scene, 6, 'freenerf', {**_llff_values(i), 'lpips': None, 'avg_error': None})
  tables.main([str(root), '--out', str(tmp_path / 'out')])
  row = _read_csv(tmp_path / 'out' / 'llff_summary.csv')[0]
  assert row['6 views LPIPS'] == '' and row['6 views Avg'] == ''
  assert float(row['6 views PSNR']) == pytest.approx(19.7)
  assert 'lpips missing for: fern' in capsys.readouterr().err


def test_same_step_twice_is_an_error(tmp_path):
  root = tmp_path / 'runs'
  first = _write(root / 'a', 'llff', 'fern', 3, 'freenerf', _llff_values(0))
  second = _write(root / 'b', 'llff', 'fern', 3, 'freenerf', _llff_values(1))
  with pytest.raises(ValueError, match='both hold'):
    tables.collect([first, second])


def test_bad_record_names_the_file(tmp_path):
  path = tmp_path / results.METRICS_FILENAME
  path.write_text(json.dumps({'dataset': 'llff'}))
  with pytest.raises(ValueError, match=str(path)):
    results.read_record(path)


def test_command_line(runs, tmp_path):
  out = tmp_path / 'cli'
  result = subprocess.run([sys.executable, '-m', 'tools.tables', str(runs), '--out', str(out)], cwd=REPO,
                          capture_output=True, text=True, check=True)
  assert 'WARNING: LLFF mipnerf 3 views' in result.stderr
  written = {pathlib.Path(p).name for p in result.stdout.split()}
  assert written == {p.name for p in out.iterdir()} and {'llff.md', 'dtu.md', 'dtu_summary_object.csv'} <= written


def test_summaries_show_the_papers_values_beside_the_runs(runs, tmp_path):
  for i, scene in enumerate(['chair', 'drums', 'ficus', 'hotdog', 'lego', 'materials', 'mic', 'ship']):
    _write(runs, 'blender', scene, 8, 'nerf', _llff_values(i))
  _write(runs, 'dtu', 'scan8', 3, 'mipnerf', _dtu_values(7))
  out = tmp_path / 'out'
  assert tables.main([str(runs), '--out', str(out), '--allow-incomplete']) == 0
  blender = _by(_read_csv(out / 'blender_summary.csv'), 'method')
  repro = "nerf (paper's repro. baseline)"  # The paper's own NeRF re-run, not DietNeRF's 14.93.
  assert float(blender[repro]['8 views PSNR']) == 13.93
  assert float(blender[repro]['8 views LPIPS']) == 0.32
  assert blender[repro]['8 views Avg'] == ''              # Not in the paper's table: empty.
  assert 'freenerf (paper)' not in blender                          # No FreeNeRF runs on Blender: no row.
  llff = _by(_read_csv(out / 'llff_summary.csv'), 'method')
  repro = "mipnerf (paper's repro. baseline)"
  assert float(llff[repro]['3 views PSNR']) == 16.11 and llff[repro]['3 views SSIM'] == ''
  dtu = _by(_read_csv(out / 'dtu_summary_object.csv'), 'method')
  assert float(dtu['freenerf (paper)']['3 views PSNR']) == 19.92
  # mip-NeRF with the identity concatenated, as the paper re-ran it, not RegNeRF's reported 8.68 / 7.64.
  dtu_full = _by(_read_csv(out / 'dtu_summary_full.csv'), 'method')
  assert float(dtu[repro]['3 views PSNR']) == 9.10 and float(dtu_full[repro]['3 views PSNR']) == 7.94


def test_seeds_are_pooled_with_mean_spread_and_n(tmp_path):
  root = tmp_path / 'runs'
  offsets = (0., 1., 2.5)  # Seed k adds offsets[k] dB to every scene.
  for k, offset in enumerate(offsets):
    for i, scene in enumerate(LLFF):
      _write(root, 'llff', scene, 3, 'freenerf', {**_llff_values(i), 'psnr': 19. + 0.2 * i + offset}, seeds=[k, k])
  assert tables.main([str(root), '--out', str(tmp_path / 'out')]) == 0
  scenes = _by(_read_csv(tmp_path / 'out' / 'llff_freenerf_3views.csv'), 'scene')
  assert scenes['fern']['seeds'] == '3' and float(scenes['fern']['PSNR']) == pytest.approx(19. + 3.5 / 3)
  assert float(scenes['fern']['PSNR std']) == pytest.approx(1.2583057, abs=1e-6)  # stdev of 0, 1, 2.5.
  assert float(scenes['fern']['SSIM std']) == 0.  # Equal over seeds.
  summary = _read_csv(tmp_path / 'out' / 'llff_summary.csv')[0]
  assert float(summary['3 views PSNR']) == pytest.approx(19.7 + 3.5 / 3)
  assert float(summary['3 views PSNR std']) == pytest.approx(1.2583057, abs=1e-6)
  assert '± 1.26' in (tmp_path / 'out' / 'llff.md').read_text()
