"""Trains FreeNeRF / mip-NeRF / NeRF from gin configs; with no arguments it runs the demo end to end.

  python train.py --gin_configs=configs/freenerf/dtu3_freenerf.gin --gin_bindings="Config.dtu_scan = 'scan21'"
  python train.py   # demo: FreeNeRF and NeRF on a generated scene, evaluated, rendered, side by side

Training resumes from the newest checkpoint of Config.checkpoint_dir, and refuses a directory holding a run with
other settings. SIGINT / SIGTERM save a checkpoint and exit (status 128 + signal); rerun the command to resume.
"""

from internal import interrupt
interrupt.one_line_when_run(__name__)  # Before the other imports: Ctrl-C while they load (seconds) is one line.

import os
import sys

import jax

from internal import cli
from internal import demo
from internal import environment
from internal.pipeline import loop
from internal.run import distributed
from internal.run import run_dir


def run_demo(bindings, stop_at_step: int = 0) -> int:
  """The demo: trains NeRF and FreeNeRF alike (configs/demo*.gin), then evaluates, renders and compares."""
  method_cfgs = demo.method_configs(bindings)  # Checks both configs and run directories before any work,
  for name in demo.METHODS:  # each directory with its method's model settings bound (gin holds them).
    with demo.method_config(name, bindings) as config:
      run_dir.check_trainable(config)
  out_dir = demo.output_dir(method_cfgs)
  for name in demo.METHODS:
    with demo.method_config(name, bindings) as config:
      status = train_and_report(config, stop_at_step)
    if status:
      return status
  if jax.process_count() > 1:
    print('Several processes trained the demo but do not evaluate it: run eval.py and render.py as one process.')
    return 0
  psnrs = demo.finish(bindings)
  print('Demo test PSNR: ' + ', '.join(f'{name} {psnr:.2f} dB' for name, psnr in psnrs.items()) +
        f'; side by side in {os.path.join(out_dir, demo.PICTURE)!r}, run directories in {out_dir!r}.')
  return 0


def main(argv=None) -> int:
  """CLI entry point; returns the exit status."""
  parser = cli.flag_parser(__doc__.split('\n')[0])
  parser.add_argument('--stop_at_step', type=int, default=0,
                      help='save a checkpoint and exit after this step (resume later with the same command)')
  distributed.add_flags(parser)
  args = parser.parse_args(argv)
  distributed.initialize(args)
  environment.report_startup()
  if not args.gin_configs:
    return run_demo(args.gin_bindings, args.stop_at_step)
  return train_and_report(cli.config_from_flags(args), args.stop_at_step)


def train_and_report(config, stop_at_step: int = 0) -> int:
  """Trains one run and prints how it ended; returns the exit status (128 + signal when stopped)."""
  result = loop.train(config, stop_at_step)
  step = int(result.state.step)
  if result.signum is not None:
    print(f'Stopped by signal {result.signum} at step {step}; checkpoint saved in '
          f'{os.path.abspath(result.run_dir)!r}. Run the same command again to resume.')
    return cli.signal_status(result.signum)
  print(f'Trained to step {step}; run directory {os.path.abspath(result.run_dir)!r}.')
  if result.skipped:
    print(f'{result.skipped} update(s) were skipped for non-finite values (see the log above and '
          'train/skipped_steps in tensorboard).')
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
