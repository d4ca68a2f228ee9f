"""The ledger of paper-length runs: its file, the plan, the TF32 follow-up rule, and bench/lease.sh end to end on the
CPU at a tiny size (a generated scene's pack, 30 steps) through budget cuts, unpacked as a commit would be.

On the CPU the lease skips what only a GPU does (timing the step variants and RegNeRF's step, the fused layer's
GPU tests: its plan says so) and installs no wheels (.whl is absent here); everything else runs as in a window.
"""

import json
import os
import subprocess
import sys
import tarfile

import gin
import jax
import numpy as np
import pytest

from bench import ledger as ledger_lib
from bench import ledger_commit
from bench import prepare_lease
from conftest import SHARED_DATA
from internal import config_loader
from internal.datasets import packed
from internal.evaluation import evaluate
from internal.evaluation import learning_curve
from internal.pipeline import loop
from tools import tables

ROOT = ledger_lib.ROOT
TINY_RUN = ['MLP.net_depth = 2', 'MLP.net_width = 32', 'MLP.net_width_viewdirs = 16', 'MipNerfModel.num_samples = 16',
            'Config.batch_size = 128', 'Config.print_every = 5', 'Config.render_chunk_size = 1280',
            'Config.lr_delay_steps = 10', 'Config.freq_reg_end = 27', 'Config.compute_lpips = False']
TINY_LEDGER = f"""
precision = 'float32'
curve_every = 10
checkpoint_every = 5
seed_spread_db = 100.0
variants_seconds = 60
variants = ['base']

[pack.tiny]
gin = 'configs/demo.gin'
data = 'scene'
bindings = ['Config.generated_size = (32, 40)']

[[run]]
name = 'tiny'
gin = 'configs/demo.gin'
pack = 'tiny'
steps = 30
paper = ['blender', 'freenerf', 8]
metric = 'psnr'
released = 'A tiny run.'
bindings = {json.dumps(TINY_RUN)}

[[run]]
name = 'tiny_tf32'
follow_up_of = 'tiny'
precision = 'default'
"""


@pytest.fixture(name='tiny')
def tiny_fixture(tmp_path_factory):
  """(ledger, data folder) of the tiny ledger, its pack made by tools.pack_scene as bench.prepare_lease makes them."""
  folder = tmp_path_factory.mktemp('tiny_ledger')
  (folder / 'ledger.toml').write_text(TINY_LEDGER)
  ledger = ledger_lib.load(str(folder / 'ledger.toml'))
  prepare_lease.make_packs(ledger, str(folder), str(folder / 'data'))
  return ledger, str(folder / 'data')


def test_the_ledger_holds_the_released_runs_in_order():
  ledger = ledger_lib.load()
  assert [r.name for r in ledger.runs] == ['freenerf_dtu3_scan24', 'freenerf_dtu3_scan24_tf32', 'mipnerf_dtu3_scan24',
                                           'freenerf_llff3_fern', 'mipnerf_llff3_fern']
  for run in ledger.runs:
    gin.clear_config()
    released = config_loader.load_config([os.path.join(ROOT, run.gin)], ["Config.data_dir = 'x'"])
    assert run.steps == released.max_steps and run.metric in tables.PAPER[run.paper]
    assert run.precision == ('default' if run.follow_up_of else 'bfloat16')
  assert [r.steps for r in ledger.runs] == [43945, 43945, 43945, 69768, 69768]
  follow = ledger.runs[1]
  assert follow.follow_up_of == ledger.runs[0].name and follow.gin == ledger.runs[0].gin and follow.pack == 'dtu_scan24'
  # The variants a window times are ones a run can train with, the plain step first.
  assert ledger_lib.timed_variants(ledger)[0] == 'base' and 'pallas_fewer_passes' in ledger.variants


def test_a_ledger_variant_no_run_can_train_with_is_named(tmp_path):
  path = tmp_path / 'ledger.toml'
  path.write_text(TINY_LEDGER.replace("variants = ['base']", "variants = ['base', 'cublaslt', 'no_such']"))
  with pytest.raises(ValueError, match=r"variants \['cublaslt', 'no_such'\] are not step variants a run can train"):
    ledger_lib.timed_variants(ledger_lib.load(str(path)))


@pytest.mark.skipif(not (SHARED_DATA / 'dtu' / 'dtu_scan24').is_dir(), reason=f'no DTU scan24 under {SHARED_DATA}')
def test_every_run_trains_on_its_pack_and_scores_its_curve_on_every_test_view(tmp_path):
  ledger = ledger_lib.load()
  prepare_lease.make_packs(ledger, str(SHARED_DATA), str(tmp_path))
  for run in ledger.runs:
    gin.clear_config()
    bindings = ledger_lib.train_bindings(ledger, run, str(tmp_path), str(tmp_path / run.name), [])
    config = config_loader.load_config([os.path.join(ROOT, run.gin)], bindings)
    path = ledger_lib.pack_path(ledger, run, str(tmp_path))
    packed.check_settings(config, packed.read_pack(path)[0], path)  # The pack's data is this run's.
    assert config.curve_spread_views == (13 if run.pack == 'dtu_scan24' else 3) and config.curve_every == 4000
    assert config.precision == run.precision and config.max_steps == run.steps


def _window(**overrides) -> dict:
  return {'device': 'NVIDIA H100 80GB HBM3', 'platform': 'gpu', 'jax': '0.11.2', 'budget_seconds': 540,
          'code': 'abc', 'kind': 'nvidia_h100_80gb_hbm3', 'time_variants': True, **overrides}


def test_the_plan_says_how_far_each_run_is_and_what_this_window_does(tmp_path):
  lines = ledger_lib.plan_lines(ledger_lib.load(), str(tmp_path / 'results'), str(tmp_path / 'work'), _window())
  assert lines[0] == ('Ledger bench/ledger.toml: 5 runs; this window: NVIDIA H100 80GB HBM3 (gpu), jax 0.11.2, '
                      'budget 540 s')
  assert lines[1] == ('  1. freenerf_dtu3_scan24: 0 of 43,945 steps (0%), bfloat16, '
                      'configs/freenerf/dtu3_freenerf.gin')
  assert lines[2].endswith('[follow-up: decided once freenerf_dtu3_scan24 is evaluated]')
  assert lines[6].startswith('Step variants: code abc not timed on nvidia_h100_80gb_hbm3 yet: timing them')
  assert lines[7].startswith('Next: train freenerf_dtu3_scan24 from step 0 of 43,945 until the budget')
  cpu = ledger_lib.plan_lines(ledger_lib.load(), str(tmp_path), str(tmp_path), _window(platform='cpu',
                                                                                       time_variants=False))
  assert cpu[6] == 'Step variants: not timed (GPU only; this is a cpu): the run takes base'


def _evaluated(results, run, value):
  """Commits run as evaluated at its last step with value as its metric."""
  ledger_lib.write_json(str(results / run.name / ledger_lib.STATE), {'step': run.steps, 'evaluated': True,
                                                                      'windows': []})
  ledger_lib.write_json(str(results / run.name / 'metrics.json'), {'step': run.steps, 'eval_factor': 1,
                                                                    'means': {run.metric: value}})


@pytest.mark.parametrize('short, goes', [(1.0, True), (0.3, False)])
def test_the_tf32_follow_up_goes_next_only_when_the_run_falls_short_by_more_than_a_seeds_spread(tmp_path, short,
                                                                                               goes):
  ledger = ledger_lib.load()
  first, follow, mipnerf = ledger.runs[:3]
  assert ledger_lib.next_run(ledger, str(tmp_path), str(tmp_path / 'w')) == (first, 'train')
  _evaluated(tmp_path, first, ledger_lib.paper_value(first) - short)
  decided, why = ledger_lib.follow_up(ledger, follow, str(tmp_path), str(tmp_path / 'w'))
  assert decided is goes and why.startswith(f'freenerf_dtu3_scan24 is +{short:.2f} dB short of the paper\'s '
                                            'psnr_masked 19.92')
  assert ledger_lib.next_run(ledger, str(tmp_path), str(tmp_path / 'w')) == ((follow if goes else mipnerf), 'train')


@pytest.mark.parametrize('text, message', [
    ('curve_every = 1', "run"),
    ("curve_every = 1\ncheckpoint_every = 1\nseed_spread_db = 0.5\nvariants_seconds = 1\n[[run]]\nname = 'a'\n",
     r"run 1: gin = None; expected a str"),
    ("[[run]]\nname = 'b'\nfollow_up_of = 'a'\n", r"run 1: follow_up_of = 'a'; expected a run named before it"),
    ('x = ', 'expected a TOML file like bench/ledger.toml')])
def test_a_bad_ledger_is_named(tmp_path, text, message):
  (tmp_path / 'l.toml').write_text(text)
  with pytest.raises(ValueError, match=message):
    ledger_lib.load(str(tmp_path / 'l.toml'))


def _lease(tmp_path, name, ledger, data, results, **env):
  """Runs bash bench/lease.sh into tmp_path/name; returns (OUT, the lease's output)."""
  out = tmp_path / name
  env = {**os.environ, 'OUT': str(out), 'PYTHON': sys.executable, 'LEASE_WORK': str(tmp_path / f'{name}_work'),
         'LEDGER': ledger.path, 'RESULTS': str(results), 'DATA': data, 'LEASE_ON_CPU': '1', **env}
  result = subprocess.run(['bash', 'bench/lease.sh'], cwd=ROOT, env=env, text=True, capture_output=True, timeout=900)
  assert result.returncode == 0, result.stdout + result.stderr
  assert (out / 'lease.log').read_text() == result.stdout  # Everything it printed comes back.
  return out, result.stdout


def _uninterrupted(ledger, run, data, run_dir):
  """The parameters of the run trained in one go, as the lease trains it."""
  gin.clear_config()
  config = config_loader.load_config([os.path.join(ROOT, run.gin)],
                                     ledger_lib.train_bindings(ledger, run, data, str(run_dir), []))
  return loop.train(config).state.params


def _committed_style(ledger, run, data, results, tmp_path, step):
  """<results>/<run>/ as a window's commit leaves it: the run trained to step, its folder as checkpoint.tar.gz."""
  gin.clear_config()
  run_dir = tmp_path / 'first_window'
  config = config_loader.load_config([os.path.join(ROOT, run.gin)],
                                     ledger_lib.train_bindings(ledger, run, data, str(run_dir), []))
  loop.train(config, stop_at_step=step)
  os.makedirs(results / run.name)
  ledger_lib._tar(str(results / run.name / ledger_lib.CHECKPOINT), str(run_dir),  # pylint: disable=protected-access
                  lambda member: ledger_lib._keep(member, step))  # pylint: disable=protected-access
  ledger_lib.write_json(str(results / run.name / ledger_lib.STATE),
                        {'step': step, 'evaluated': False, 'variant': 'base', 'variant_bindings': [], 'windows': []})


def _flat_params(params) -> dict:
  return {'/'.join(k.key for k in path): np.asarray(x) for path, x in jax.tree_util.tree_leaves_with_path(params)}


@pytest.mark.slow
def test_the_lease_resumes_through_budget_cuts_to_the_uninterrupted_runs_parameters(tiny, tmp_path):
  ledger, data = tiny
  run = ledger.runs[0]
  results = tmp_path / 'results'
  reference = _flat_params(_uninterrupted(ledger, run, data, tmp_path / 'uninterrupted'))
  reference_curve = learning_curve.read_rows(str(tmp_path / 'uninterrupted' / learning_curve.CSV_FILE))
  _committed_style(ledger, run, data, results, tmp_path, 8)

  # A window too short to train (its plan and `next` fit, training's 60 s do not, beside the reserve and the
  # grace): the committed checkpoint goes back as it came, the window is recorded.
  out, printed = _lease(tmp_path, 'starved', ledger, data, results, BUDGET='165')
  assert '== train_tiny: skipped' in printed and 'Next: train tiny from step 8 of 30 until the budget' in printed
  ledger_commit.unpack(ledger, str(out), str(results))
  assert ledger_lib.state(str(results), run)['windows'][-1]['to_step'] == 8

  # A window whose budget ends at step 17 (STOP_AT_STEP stands for the clock), then one that finishes the run.
  out, printed = _lease(tmp_path, 'cut', ledger, data, results, STOP_AT_STEP='17')
  assert 'Step variants: not timed (GPU only; this is a cpu): the run takes base' in printed
  with tarfile.open(out / 'run_tiny.tar.gz') as tar:  # The newest checkpoint only, no lock.
    assert sorted(n for n in tar.getnames() if n.startswith('./checkpoints/') and n.count('/') == 2) == \
        ['./checkpoints/17']
  assert not (out / 'eval_tiny.tar.gz').exists()
  ledger_commit.unpack(ledger, str(out), str(results))
  out, printed = _lease(tmp_path, 'finish', ledger, data, results)
  assert 'tiny: steps 17 -> 30 of 30, evaluated' in printed and '== eval_tiny: status 0' in printed
  assert len(os.listdir(out)) <= ledger_lib.FILES_BACK
  ledger_commit.unpack(ledger, str(out), str(results))

  committed = results / 'tiny'
  with np.load(committed / ledger_commit.MODEL) as model:
    assert set(model.files) == set(reference)
    for key, value in reference.items():
      np.testing.assert_array_equal(model[key], value, err_msg=key)  # Bit for bit.
  rows = learning_curve.read_rows(str(committed / learning_curve.CSV_FILE))
  assert [r['step'] for r in rows] == [r['step'] for r in reference_curve] == [10, 20, 30]
  assert [r['psnr'] for r in rows] == [r['psnr'] for r in reference_curve]
  assert all(a['seconds'] < b['seconds'] and a['compile_seconds'] <= b['compile_seconds']
             for a, b in zip(rows, rows[1:]))
  record = ledger_lib.state(str(results), run)
  assert record['evaluated'] and record['step'] == 30 and not (committed / ledger_lib.CHECKPOINT).exists()
  assert [(w['from_step'], w['to_step']) for w in record['windows']] == [(8, 8), (8, 17), (17, 30)]
  # Seconds per window add up to the curve's clock; each resumed window compiled its step again.
  assert sum(w['seconds'] for w in record['windows']) == pytest.approx(record['windows'][-1]['seconds_total'])
  assert record['windows'][1]['compile_seconds'] > 0 and record['windows'][2]['compile_seconds'] > 0
  assert json.loads((committed / 'metrics.json').read_text())['means']['psnr'] == pytest.approx(rows[-1]['psnr'])
  readme = (committed / 'README.md').read_text()
  assert '| 8 -> 17 |' in readme and '## Result' in readme and (committed / 'learning_curve.png').is_file()
  assert '| [tiny](tiny/README.md) | 30 of 30 | 3 | evaluated |' in (results / 'README.md').read_text()
  assert (committed / 'logs').is_dir() and len(os.listdir(committed / 'logs')) == 3  # Two trainings, one evaluation.

  # The follow-up (tiny at TF32) was decided once the run was evaluated: short of the paper's 24.26 by less than
  # the tiny ledger's 100 dB, so it does not go; nothing is left.
  assert '[follow-up: decided once tiny is evaluated]' in printed
  assert ledger_lib.follow_up(ledger, ledger.runs[1], str(results), str(tmp_path))[0] is False
  assert ledger_lib.next_run(ledger, str(results), str(tmp_path / 'none')) is None
  with pytest.raises(ValueError, match='holds tiny at step 17, older than the committed step 30'):
    ledger_commit.unpack(ledger, str(tmp_path / 'cut'), str(results))


def test_a_finished_runs_model_is_a_run_folder_eval_reads(tiny, tmp_path):
  ledger, data = tiny
  run = ledger.runs[0]
  params = _flat_params(_uninterrupted(ledger, run, data, tmp_path / 'run'))
  (tmp_path / 'results' / run.name).mkdir(parents=True)
  np.savez(tmp_path / 'results' / run.name / ledger_commit.MODEL, **params)
  ledger_commit.model_run_dir(ledger, run.name, str(tmp_path / 'results'), data, str(tmp_path / 'model'))
  psnrs = []
  for folder in ('model', 'run'):  # The model's run folder, and the run that trained it.
    gin.clear_config()
    psnrs.append(evaluate.evaluate(config_loader.load_config(
        [os.path.join(ROOT, run.gin)], ledger_lib.train_bindings(ledger, run, data, str(tmp_path / folder), [])))
                 ['means']['psnr'])
  assert psnrs[0] == psnrs[1]


def test_the_preparation_counts_what_travels_and_prints_the_one_call():
  call = prepare_lease.device_call()
  assert call == "run(command=\"bash bench/lease.sh\", carry=['.whl', '.devdata'], timeout_s=590)" and len(call) < 2000
  sizes = prepare_lease.travelling()
  assert sizes['tree'] > 10 * 2**20 and set(sizes) == {'tree', '.whl', '.devdata'}
  assert prepare_lease.pinned('tensorboardX') == 'tensorboardX==2.6.5'
  with open(os.path.join(ROOT, '.gitignore')) as f:
    ignored = f.read().split()
  assert '/.whl/' in ignored and '/.devdata/' in ignored  # Carried, never committed.


def test_a_new_run_whose_variant_fails_goes_again_with_base_and_a_resumed_one_keeps_its_own(tiny, tmp_path):
  ledger, data = tiny
  run, work = ledger.runs[0], tmp_path / 'work'
  (work / 'runs' / run.name).mkdir(parents=True)
  (work / 'runs' / run.name / 'config.json').write_text('{}')  # What the failed training wrote.
  done = {run.name: {'from_step': 0, 'packed': False, 'variant': 'pallas', 'variant_bindings': ['MLP.x = 1']}}
  ledger_lib.write_json(str(work / 'outcomes.json'), done)
  assert ledger_lib.retry_base(ledger, str(work), data)
  assert not os.listdir(work / 'runs' / run.name)
  args = (work / f'{run.name}.args').read_text().splitlines()
  assert args[0] == run.gin and 'MLP.x = 1' not in args and f"Config.max_steps = {run.steps}" in args
  outcome = ledger_lib.outcomes(str(work))[run.name]
  assert (outcome['variant'], outcome['variant_bindings'], outcome['failed_variant']) == ('base', [], 'pallas')
  assert not ledger_lib.retry_base(ledger, str(work), data)  # Base failed too: nothing left to try.
  ledger_lib.write_json(str(work / 'outcomes.json'), {run.name: {**done[run.name], 'from_step': 8}})
  assert not ledger_lib.retry_base(ledger, str(work), data)


# The lease's python in the worst case: a variant's training fails at once; any other training (stopped at a step by
# STOP_AT_STEP, its checkpoint saved) then outlasts its limit and the grace (SIGKILL); packing a run or the window
# outlasts its limit.
WORST_CASE_PYTHON = """#!/usr/bin/env bash
case " $* " in
  *" train.py "*folded_bias*) echo 'this variant fails'; exit 1;;
  *" train.py "*) "{python}" "$@" & trap '' TERM; wait $!; sleep 600;;
  *" bench.ledger pack"*) trap '' TERM; sleep 600;;
  *) exec "{python}" "$@";;
esac
"""


@pytest.mark.slow
def test_the_worst_case_window_ends_within_its_budget_and_keeps_what_it_trained(tmp_path):
  (tmp_path / 'ledger.toml').write_text(TINY_LEDGER.replace('steps = 30', 'steps = 100000').replace(
      'curve_every = 10', 'curve_every = 100000'))
  ledger, data = ledger_lib.load(str(tmp_path / 'ledger.toml')), str(tmp_path / 'data')
  assert prepare_lease.make_packs(ledger, str(tmp_path), data) == 0
  results, run = tmp_path / 'results', ledger.runs[0]
  # A new run takes the fastest correct variant timed for this code on this machine: folded_bias, as timed here.
  key = f'cpu/{ledger_lib.code_hash()}'
  ledger_lib.write_json(str(results / ledger_lib.TIMED), {key: {'folder': 'variants/cpu'}})
  ledger_lib.write_json(str(results / 'variants' / 'cpu' / 'step_variants.json'), {'platform': 'cpu', 'results': {
      'float32': {'base': {'step_seconds': 2.0, 'loss': 1.0},
                  'folded_bias': {'step_seconds': 1.0, 'loss_difference': 0.0, 'gradient_relative_l2': 0.0,
                                  'gradient_worst_relative_l2': 0.0}}}})
  python = tmp_path / 'python'
  python.write_text(WORST_CASE_PYTHON.format(python=sys.executable))
  python.chmod(0o755)
  budget = 220  # Plan, `next` and the retry (about 30 s), training (about 110 s), 5 s of grace, the reserve (75 s).

  out, printed = _lease(tmp_path, 'worst', ledger, data, results, BUDGET=str(budget), GRACE='5', PYTHON=str(python),
                        STOP_AT_STEP='5')
  assert '== train_tiny: status 1 after' in printed  # The variant failed: not a cut.
  assert 'tiny: training with variant folded_bias failed; again from step 0 with base' in printed
  assert printed.count('== retry_tiny:') == 2  # Its start and its end: the one retry.
  assert '== train_tiny_base: status 137 after' in printed and ': cut by the budget' in printed
  assert '== pack tiny failed: the run folder as it is' in printed
  assert int(printed.split('== lease done after ')[1].split('s:')[0]) <= budget
  assert sorted(os.listdir(out)) == ['lease.log', 'run_tiny.tar.gz', 'window.tar.gz']

  ledger_commit.unpack(ledger, str(out), str(results))
  record = ledger_lib.state(str(results), run)
  assert record['step'] == 5 and record['variant'] == 'base', printed
  assert (results / run.name / ledger_lib.CHECKPOINT).is_file()
  assert [(w['from_step'], w['to_step']) for w in record['windows']] == [(0, 5)]
