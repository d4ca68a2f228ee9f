"""Evaluates the newest checkpoint of a run on its test views: metrics.json, a per-image CSV and images.

  python eval.py --gin_configs=configs/freenerf/dtu3_freenerf.gin --gin_bindings="Config.dtu_scan = 'scan21'"

Pass the gin configs and bindings used for training (none: the demo's FreeNeRF, configs/demo.gin then
configs/demo_forward.gin). Outputs go to <Config.checkpoint_dir>/test_preds_step_<step>/ (or into
Config.output_dir, when set): metrics.json (internal/evaluation/results.py's schema), metrics.csv, and per view
color_<id>.png, depth_<id>.png (turbo map of -log depth, normalized by its 0.5 / 99.5 percentiles) and
opacity_<id>.png. Metrics use the unclipped renderings.
Config.eval_test_ids (positions in the test split) and Config.eval_factor (lower resolution) give quick looks,
recorded as "complete": false. A finished evaluation is never replaced unless Config.overwrite = True.
"""

from internal import interrupt
interrupt.one_line_when_run(__name__)  # Before the other imports: Ctrl-C while they load (seconds) is one line.

import json
import sys

from internal import cli
from internal import environment
from internal.evaluation import evaluate


def main(argv=None) -> int:
  """CLI entry point; returns the exit status."""
  args = cli.flag_parser(__doc__.split('\n')[0]).parse_args(argv)
  environment.report_startup()
  record = evaluate.evaluate(cli.config_from_flags(args))
  means = {k: v for k, v in record['means'].items() if v is not None}
  print(f'step {record["step"]}, {len(record["per_image"])} views: {json.dumps(means)}')
  if record['lpips_missing_reason']:
    print(f'LPIPS not computed: {record["lpips_missing_reason"]}')
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
