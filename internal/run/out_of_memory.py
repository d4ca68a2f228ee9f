"""Running out of accelerator or host memory as a one-line user error naming the setting that sizes the work."""

import contextlib

import jax

MIB, GIB = 2.**20, 2.**30


class OutOfMemoryError(RuntimeError):
  """XLA could not allocate what a compiled training step or rendering needs (RESOURCE_EXHAUSTED), or numpy what
  the host's batch needs (MemoryError)."""


def is_out_of_memory(err: BaseException) -> bool:
  """True for the error jax raises when XLA cannot allocate device memory (JaxRuntimeError RESOURCE_EXHAUSTED)."""
  return isinstance(err, jax.errors.JaxRuntimeError) and 'RESOURCE_EXHAUSTED' in str(err)


def compiled_bytes(jitted, *args):
  """Bytes XLA's memory analysis gives jitted(*args) compiled (arguments, outputs, temporaries), or None."""
  try:
    abstract = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), args)  # Donated arrays keep shapes.
    return compiled_size(jitted.lower(*abstract).compile())
  except Exception:  # pylint: disable=broad-except  (the estimate only adds to the message; none is fine)
    return None


def compiled_size(compiled) -> int:
  """Bytes a compiled XLA program needs when it runs (arguments, outputs, temporaries), by XLA's memory analysis."""
  stats = compiled.memory_analysis()
  return (stats.argument_size_in_bytes + stats.output_size_in_bytes + stats.temp_size_in_bytes -
          stats.alias_size_in_bytes)


def host_available_bytes():
  """Bytes of host memory available now without swapping (Linux's MemAvailable), or None where unknown."""
  try:
    with open('/proc/meminfo') as f:
      found = [line.split()[1] for line in f if line.startswith('MemAvailable:')]
  except OSError:
    return None
  return int(found[0]) * 1024 if found else None


def device_available_bytes(device, host_in_use: int = 0):
  """Bytes device can still allocate: its allocator's limit less what is in use; a CPU's is the host's available
  memory less host_in_use (what the host side of the work will take). None where unknown."""
  stats = device.memory_stats() or {}
  if 'bytes_limit' in stats:
    return stats['bytes_limit'] - stats.get('bytes_in_use', 0)
  host = host_available_bytes()
  return None if host is None else host - host_in_use


def largest_fitting(needed, available: int) -> int:
  """The largest n >= 1 with needed(n) <= available, for needed increasing in n; 0 when needed(1) does not fit."""
  if needed(1) > available:
    return 0
  low, high = 1, 2
  while needed(high) <= available:
    low, high = high, 2 * high
  while high - low > 1:  # needed(low) fits, needed(high) does not.
    middle = (low + high) // 2
    low, high = (middle, high) if needed(middle) <= available else (low, middle)
  return low


def size_text(num_bytes: int) -> str:
  """'1.23 GiB' from 1 GiB on, else '12.3 MiB'."""
  return f'{num_bytes / GIB:.2f} GiB' if num_bytes >= GIB else f'{num_bytes / MIB:.1f} MiB'


@contextlib.contextmanager
def naming_setting(what: str, setting: str, needed_bytes=lambda: None):
  """Turns an out-of-memory error in the block into OutOfMemoryError: what ran out, XLA's estimate, what to lower."""
  try:
    yield
  except jax.errors.JaxRuntimeError as err:
    if not is_out_of_memory(err):
      raise
    needed = needed_bytes()
    estimate = f'; XLA estimates {size_text(needed)} for it compiled' if needed else ''
    reason = str(err).strip().splitlines()[0].rstrip('.')
    raise OutOfMemoryError(f'out of accelerator memory {what} ({reason}{estimate}); lower {setting}') from err


@contextlib.contextmanager
def naming_host_setting(what: str, setting: str):
  """Turns numpy's MemoryError in the block (host memory or the process's address-space limit ran out, before
  XLA's allocator saw anything) into OutOfMemoryError: what ran out, numpy's words, what to lower."""
  try:
    yield
  except MemoryError as err:
    raise OutOfMemoryError(f'out of host memory {what} ({str(err).strip().rstrip(".")}); lower {setting}') from err
