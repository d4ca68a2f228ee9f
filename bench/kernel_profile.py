"""Where a compiled step's device time goes: a profiler trace of a few steps, per kind of kernel and per kernel.

The trace's device lines (a GPU's streams) hold one event per kernel, named by the kernel and, for kernels XLA
launched, carrying the HLO operation they run ('hlo_op'). A kernel's kind comes from those two names: the fused
dense layer's Pallas kernels, matrix products (cuBLAS, cuBLASLt, Triton GEMM fusions), copies and transposes,
reductions, other fusions (element-wise work), and the rest. On a CPU the trace has no device lines and the summary
says so.
"""

import collections
import glob
import gzip
import json
import os
import re
import shutil
import tempfile

import jax

# First match wins: a Triton GEMM fusion is a matmul, a transpose fusion a transpose, a reduce fusion a reduction.
KINDS = (('fused dense (Pallas)', r'fused_dense'),  # internal/models/fused_dense.py's kernels, by their names.
         ('matmul', r'gemm|xmma|cutlass|cublas|nvjet|gmma|\bdot'),
         ('copy/transpose', r'copy|transpose|memcpy|memset|concatenate|dynamic.update.slice'),
         ('reduction', r'reduce|scatter'),
         ('element-wise fusion', r'fusion|triton'))


def kernel_kind(kernel: str, hlo_op: str = '') -> str:
  """The kind (KINDS, else 'other') of a kernel, by its name and the HLO operation it runs."""
  text = f'{kernel} {hlo_op}'.lower()
  return next((kind for kind, pattern in KINDS if re.search(pattern, text)), 'other')


def record(run, steps: int, out_file: str = '') -> dict:
  """The perfetto trace (parsed JSON) of `steps` calls of run; kept gzipped at out_file where given."""
  with tempfile.TemporaryDirectory() as trace_dir:
    jax.profiler.start_trace(trace_dir, create_perfetto_trace=True)
    for _ in range(steps):
      run()
    jax.profiler.stop_trace()
    path = sorted(glob.glob(os.path.join(trace_dir, '**', 'perfetto_trace.json.gz'), recursive=True))[-1]
    if out_file:
      shutil.copyfile(path, out_file)
    with gzip.open(path) as f:
      trace = json.load(f)
  return trace


def events(trace):
  """The complete ('X') events of a trace, each with 'process' and 'thread' names added."""
  raw = trace['traceEvents'] if isinstance(trace, dict) else trace
  names = {('process', e['pid']): e['args']['name'] for e in raw if e.get('name') == 'process_name'}
  names.update({('thread', e['pid'], e.get('tid')): e['args']['name'] for e in raw if e.get('name') == 'thread_name'})
  return [dict(e, process=names.get(('process', e['pid']), ''),
               thread=names.get(('thread', e['pid'], e.get('tid')), '')) for e in raw if e.get('ph') == 'X']


def device_kernels(trace):
  """[(kernel name, hlo_op, microseconds)] of the kernels on the trace's device streams (none on a CPU)."""
  device = [e for e in events(trace) if e['process'].startswith('/device:')]
  streams = [e for e in device if 'stream' in e['thread'].lower()] or device
  return [(e['name'], str(e.get('args', {}).get('hlo_op', '')), float(e.get('dur', 0))) for e in streams]


def summarise(kernels, steps: int, top: int = 12) -> dict:
  """{'total_ms', 'kinds': {kind: {'ms', 'share', 'kernels'}}, 'top': [...]}: per step, from device_kernels."""
  total = sum(us for _, _, us in kernels) / 1e3 / steps
  kinds = collections.defaultdict(lambda: {'ms': 0., 'kernels': 0.})
  by_kernel = collections.Counter()
  for name, hlo_op, us in kernels:
    kind = kernel_kind(name, hlo_op)
    kinds[kind]['ms'] += us / 1e3 / steps
    kinds[kind]['kernels'] += 1 / steps
    by_kernel[(name[:80], hlo_op, kind)] += us / 1e3 / steps
  for figures in kinds.values():
    figures['share'] = figures['ms'] / total if total else 0.
  return {'total_ms': total, 'kinds': dict(sorted(kinds.items(), key=lambda kv: -kv[1]['ms'])),
          'top': [{'kernel': name, 'hlo_op': op, 'kind': kind, 'ms': ms}
                  for (name, op, kind), ms in by_kernel.most_common(top)]}


def table(title: str, summary: dict) -> str:
  """Markdown: the kinds of kernel (ms a step, share, kernels a step), then the longest kernels."""
  if not summary['kinds']:
    return f'{title}: no device kernels in the trace (a CPU run has none)'
  lines = [f"{title}: {summary['total_ms']:.2f} ms of kernels a step", '',
           '| kind | ms a step | share | kernels a step |', '|---|---|---|---|']
  lines += [f"| {kind} | {f['ms']:.2f} | {f['share']:.0%} | {f['kernels']:.0f} |"
            for kind, f in summary['kinds'].items()]
  lines += ['', '| kernel | HLO operation | kind | ms a step |', '|---|---|---|---|']
  lines += [f"| `{k['kernel']}` | {k['hlo_op']} | {k['kind']} | {k['ms']:.2f} |" for k in summary['top']]
  return '\n'.join(lines)
