"""lab.study's bad inputs: each one line on stderr naming the file, key or flag, exit status 2 (through cli.run, as
`python -m lab.study` runs); --reuse takes an export's numbers only where they agree with its metrics.json."""

import hashlib
import json

import pytest

from internal import cli
from test_study import TINY_STUDY
from lab.study import export as study_export
from lab.study import looks as study_looks
from lab.study import reuse
from lab.study import runner as study_lib
from lab.study import spec as study_spec

CELL = 'freenerf__object__views=3'


def _one_line_error(capsys, argv) -> str:
  """The stderr line of `python -m lab.study argv` run as the module runs it; asserts status 2 and one line."""
  status = cli.run(lambda: study_lib.main([str(a) for a in argv]))
  err = capsys.readouterr().err
  assert status == cli.USAGE_ERROR_STATUS and len(err.strip().splitlines()) == 1 and err.startswith('error: '), err
  return err


@pytest.mark.parametrize('text, expected', [
    ('name = "x"\n[methods.a', 'not valid TOML'),
    ('name = "x"\nseeds = 0\n[methods.a]\n[scenes.s]', 'seeds: 0; expected a count >= 1'),
    ('name = "x"\nseeds = -1\n[methods.a]\n[scenes.s]', 'seeds: -1; expected a count >= 1'),
    ('name = "x"\n[methods.a]\n[scenes.s]\n[[compare]]\na = "zip"\nb = "a"', "compare[0].a: 'zip' is not a label"),
    ('name = "x"\n[methods.a]\n[scenes.s]\n[resources]\nnum_gpus = -1', 'resources.num_gpus: -1; expected a number'),
    ('name = "x"\n[methods.a]\n[scenes.s]\n[resources]\nmax_retries = 1.5', 'max_retries: 1.5; expected an integer'),
])
def test_a_bad_study_file_is_one_line(capsys, tmp_path, text, expected):
  path = tmp_path / 'bad.toml'
  path.write_text(text)
  err = _one_line_error(capsys, [path])
  assert f'{path}:' in err and expected in err


@pytest.mark.parametrize('flags, expected', [
    (['--shard', '3/2'], "--shard '3/2'; expected K/N with 0 <= K < N"),
    (['--shard', '0/0'], "--shard '0/0'"),
    (['--shard', 'a'], "--shard 'a'"),
    (['--num-gpus', '1'], '--num-gpus: only with --executor ray'),
    (['--executor', 'ray', '--num-cpus', '-1'], 'must be >= 0'),
    (['--executor', 'ray', '--gpus', '0,1'], "--jobs and --gpus are the local executor's"),
    (['--list', '--cluster-gpus', '4'], '--cluster-gpus goes with --list --estimate'),
    (['--list', '--estimate', '--cluster-gpus', '0'], '--cluster-gpus 0; expected >= 1'),
])
def test_bad_flags_are_one_line(capsys, tmp_path, flags, expected):
  path = tmp_path / 'mini.toml'
  path.write_text(TINY_STUDY)
  assert expected in _one_line_error(capsys, [path, '--out', tmp_path / 'out', *flags])


def _export(tmp_path, record_json: str, metrics: dict = None):
  """An export folder of the study file (its mini.toml, named in provenance.json by path and SHA-256) whose
  cells.jsonl has one cell's line: its record (record_json, as written) and its evaluation (metrics)."""
  export = tmp_path / 'export'
  export.mkdir()
  (export / 'mini.toml').write_text(TINY_STUDY)
  study_file = {'path': str(export / 'mini.toml'), 'sha256': hashlib.sha256(TINY_STUDY.encode()).hexdigest()}
  (export / 'provenance.json').write_text(json.dumps({'study_file': study_file}))
  evaluation = '' if metrics is None else f', "evaluation": {json.dumps(metrics)}'
  (export / 'cells.jsonl').write_text(f'{{"cell": "{CELL}", "record": {record_json}{evaluation}}}\n')
  return export


METRICS = {'step': 20, 'complete': True, 'means': {'psnr': 10.48, 'ssim': 0.5}}
RECORD = {**METRICS, 'commit': 'abc', 'train_seconds': 10., 'eval_seconds': 2., 'steps_trained': 20,
          'steps_per_sec': 2., 'gflops_per_step': 0.1, 'peak_rss_mb': 500., 'device_peak_bytes': None}


def test_reuse_refuses_a_cell_json_the_metrics_beside_it_contradict(capsys, tmp_path):
  export = _export(tmp_path, json.dumps({**RECORD, 'means': {'psnr': 42.0, 'ssim': 0.5}}), METRICS)
  err = _one_line_error(capsys, [export / 'mini.toml', '--out', tmp_path / 'out', '--reuse', export, '--list'])
  line = export / 'cells.jsonl'
  assert f'{line} line 1 ("record") says means psnr 42.0 but' in err and f'{line} line 1 ("evaluation") says psnr 10.48' in err
  assert not (tmp_path / 'out' / 'mini' / CELL / 'cell.json').exists()


def test_reuse_takes_a_cell_whose_numbers_agree(capsys, tmp_path):
  export = _export(tmp_path, json.dumps(RECORD), METRICS)
  assert study_lib.main([str(export / 'mini.toml'), '--out', str(tmp_path / 'out'), '--reuse', str(export),
                         '--list']) == 0
  assert f'reused {CELL}' in capsys.readouterr().out
  assert study_lib.read_cell(str(tmp_path / 'out' / 'mini' / CELL))['means'] == RECORD['means']


def test_reuse_passes_over_a_cell_without_metrics(capsys, tmp_path):
  export = _export(tmp_path, json.dumps(RECORD))
  assert study_lib.main([str(export / 'mini.toml'), '--out', str(tmp_path / 'out'), '--reuse', str(export),
                         '--list']) == 0
  assert f'{CELL} not reused' in capsys.readouterr().out and not (tmp_path / 'out' / 'mini' / CELL).exists()


def test_a_merge_conflicted_cells_line_or_cell_json_is_one_line_naming_it(capsys, tmp_path):
  conflicted = '<<<<<<< HEAD\n' + json.dumps(RECORD) + '\n=======\n' + json.dumps(RECORD) + '\n>>>>>>> other\n'
  export = _export(tmp_path, json.dumps(RECORD), METRICS)
  (export / 'cells.jsonl').write_text('<<<<<<< HEAD\n' + (export / 'cells.jsonl').read_text())
  err = _one_line_error(capsys, [export / 'mini.toml', '--out', tmp_path / 'out', '--reuse', export, '--list'])
  assert f'{export / "cells.jsonl"} line 1: not valid JSON' in err and 'a merge conflict?' in err
  study = study_spec.load(export / 'mini.toml')                            # In the study folder itself too.
  (tmp_path / 'out' / 'mini' / CELL).mkdir(parents=True)
  (tmp_path / 'out' / 'mini' / CELL / 'cell.json').write_text(conflicted)
  err = _one_line_error(capsys, [export / 'mini.toml', '--out', tmp_path / 'out', '--plots-only'])
  assert f'{tmp_path / "out" / "mini" / CELL / "cell.json"}: not valid JSON' in err and study.name == 'mini'


def test_reuse_of_an_export_of_the_same_study_takes_its_looks_along(capsys, tmp_path):
  export = _export(tmp_path, json.dumps(RECORD), METRICS)
  (export / study_looks.FILE).write_text('{"seed_counts": [2, 3]}\n')
  assert study_lib.main([str(export / 'mini.toml'), '--out', str(tmp_path / 'out'), '--reuse', str(export),
                         '--list']) == 0
  assert study_looks.recorded(str(tmp_path / 'out' / 'mini')) == [2, 3] and f'reused {CELL}' in capsys.readouterr().out


def test_reuse_finds_a_study_file_recorded_by_its_path_in_another_worktree(capsys, tmp_path, monkeypatch):
  """An export written by another worktree's checkout names '../wt-x/studies/<file>'; the file of that SHA-256 under
  the same path here is the one."""
  export = _export(tmp_path, json.dumps(RECORD), METRICS)
  (tmp_path / 'repo' / 'studies').mkdir(parents=True)
  (tmp_path / 'repo' / 'studies' / 'mini.toml').write_text(TINY_STUDY)
  monkeypatch.setattr(study_export, 'REPO', str(tmp_path / 'repo'))
  provenance = json.loads((export / 'provenance.json').read_text())
  provenance['study_file']['path'] = '../wt-gone/studies/mini.toml'
  (export / 'provenance.json').write_text(json.dumps(provenance))
  assert reuse.exported_study(str(export)).name == 'mini'
  provenance['study_file']['sha256'] = '0' * 64
  (export / 'provenance.json').write_text(json.dumps(provenance))
  with pytest.raises(study_spec.StudyError, match='it ran ../wt-gone/studies/mini.toml of SHA-256 000000000000'):
    reuse.exported_study(str(export))


def test_an_export_names_its_study_file_by_its_path_in_its_own_checkout(tmp_path):
  (tmp_path / 'wt-x' / 'studies').mkdir(parents=True)
  (tmp_path / 'wt-x' / '.git').write_text('gitdir: elsewhere\n')  # A worktree's .git is a file.
  (tmp_path / 'wt-x' / 'studies' / 'mini_dtu.toml').write_text(TINY_STUDY)
  assert study_export.checkout_path(str(tmp_path / 'wt-x' / 'studies' / 'mini_dtu.toml')) == 'studies/mini_dtu.toml'
  assert study_export.checkout_path('studies/depth_prior_cup.toml') == 'studies/depth_prior_cup.toml'
