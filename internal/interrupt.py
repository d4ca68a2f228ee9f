"""Ctrl-C (SIGINT) before a command finishes as one line, from the first statement of a script on.

It imports only the standard library, so a script sets it up before its other imports, which take seconds (jax,
orbax): Ctrl-C while they load prints the line that cli.run prints once main runs, instead of a traceback.

The KeyboardInterrupt that Python's handler raises does not always come out as one. Raised in the initialization of
a compiled module (jaxlib's, while `import jax` runs) it becomes an ImportError ('Encountered an error while
initializing the extension'), which the module may also print first, or crashes the process; in a callback (a
garbage collection's) Python reports it as 'Exception ignored in ...' and goes on; a library's fallback (`except
ImportError:`) may swallow it. So the handler records that SIGINT arrived and raises KeyboardInterrupt only where it
stops the command: in a compiled module's initialization it signals SIGINT again RETRY_SECONDS later instead, as
the unraisable hook does for one that a callback dropped. Whatever exception then ends the command is reported as
the interruption, and cli.run stops before main when the imports swallowed one.
"""

import atexit
import contextlib
import importlib.machinery
import os
import signal
import sys
import threading

MESSAGE = ('interrupted: stopped by Ctrl-C (SIGINT) before the command finished; what it wrote is kept, and the '
           'same command run again finishes the work')
RETRY_SECONDS = 0.05


class Recorder:
  """The SIGINT handler: raises KeyboardInterrupt as Python's own does where that stops the command, and records
  that SIGINT arrived."""

  def __init__(self):
    self.received = False
    self.owed = False  # A KeyboardInterrupt is still to be raised (put off, or dropped by a callback).
    self._previous = {}

  def __call__(self, signum, frame):
    del signum
    self.received = True
    self.owed = _breaks_there(frame)
    if self.owed:
      self._signal_again()
      return
    raise KeyboardInterrupt

  def _signal_again(self) -> None:
    """Signals SIGINT to the main thread again in RETRY_SECONDS, unless a KeyboardInterrupt was raised meanwhile."""
    def again():
      if self.owed:
        signal.pthread_kill(threading.main_thread().ident, signal.SIGINT)
    timer = threading.Timer(RETRY_SECONDS, again)
    timer.daemon = True
    timer.start()

  def raise_if_received(self) -> None:
    """Raises KeyboardInterrupt when a SIGINT arrived (e.g. during the imports, its exception swallowed there)."""
    if self.received:
      self.owed = False
      raise KeyboardInterrupt

  def _unraisable(self, unraisable) -> None:
    """sys.unraisablehook: a KeyboardInterrupt that a callback dropped is signalled again, to stop the command where
    it runs; other reports go to the previous hook."""
    if isinstance(unraisable.exc_value, KeyboardInterrupt) and self.received:
      self.owed = True
      self._signal_again()
    else:
      self._previous['unraisable'](unraisable)

  def install(self) -> bool:
    """Handles SIGINT (and dropped KeyboardInterrupts) unless SIGINT has a handler other than Python's default
    (ignored, as under nohup, or another's) or this is not the main thread (which alone sets handlers); True when
    installed."""
    if (threading.current_thread() is not threading.main_thread()
        or signal.getsignal(signal.SIGINT) is not signal.default_int_handler):
      return False
    self._previous = {'signal': signal.signal(signal.SIGINT, self), 'unraisable': sys.unraisablehook}
    sys.unraisablehook = self._unraisable
    return True

  def uninstall(self) -> None:
    """Puts back what install replaced, where nothing replaced it since (e.g. cli.run ignoring SIGINT to its exit)."""
    if signal.getsignal(signal.SIGINT) is self:
      signal.signal(signal.SIGINT, self._previous['signal'])
    if sys.unraisablehook == self._unraisable:
      sys.unraisablehook = self._previous['unraisable']


# Where a KeyboardInterrupt breaks instead of stopping: a compiled module's initialization, the unraisable hook.
_BREAKING_CODE = (importlib.machinery.ExtensionFileLoader.create_module.__code__,
                  importlib.machinery.ExtensionFileLoader.exec_module.__code__, Recorder._unraisable.__code__)


def _breaks_there(frame) -> bool:
  """True when frame runs (also through code it called) where a KeyboardInterrupt breaks (_BREAKING_CODE)."""
  while frame is not None:
    if frame.f_code in _BREAKING_CODE:
      return True
    frame = frame.f_back
  return False


def installed():
  """The Recorder handling SIGINT, or None."""
  handler = signal.getsignal(signal.SIGINT)
  return handler if isinstance(handler, Recorder) else None


@contextlib.contextmanager
def recording():
  """Yields the Recorder handling SIGINT: the installed one (a script's first statement), else one installed for
  the block (one that never receives, when SIGINT is ignored)."""
  recorder = installed()
  if recorder is not None:
    yield recorder
    return
  recorder = Recorder()
  recorder.install()
  try:
    yield recorder
  finally:
    recorder.uninstall()


class _OneLineHook:
  """sys.excepthook printing MESSAGE, once, for an exception that ends the process once SIGINT arrived (a
  KeyboardInterrupt, or what an interrupted import made of it); previous for the rest."""

  def __init__(self, previous, recorder: Recorder):
    self.previous, self.recorder = previous, recorder
    self.told = False
    self.ended = False  # An exception other than KeyboardInterrupt ends the process after a SIGINT.

  def __call__(self, kind, value, traceback):
    if not (issubclass(kind, KeyboardInterrupt) or self.recorder.received):
      self.previous(kind, value, traceback)
      return
    if not self.told:  # A compiled module prints its interrupted initialization's error, then raises another.
      print(MESSAGE, file=sys.stderr)
    self.told = True
    self.ended = self.ended or not issubclass(kind, KeyboardInterrupt)


def _exit_by_sigint(hook: _OneLineHook) -> None:
  """At exit: ends the process by SIGINT, as Python ends it after a KeyboardInterrupt, when another exception ended
  it after a SIGINT."""
  if hook.ended:
    for stream in (sys.stdout, sys.stderr):
      stream.flush()
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    os.kill(os.getpid(), signal.SIGINT)


def one_line_when_run(module_name: str) -> None:
  """In a script run as a command (module_name '__main__'), an exception that ends the process after Ctrl-C prints
  MESSAGE; the process exits as SIGINT stopped it (status 130 in a shell). Imported as a module: nothing."""
  if module_name != '__main__':
    return
  recorder = Recorder()
  recorder.install()
  sys.excepthook = _OneLineHook(sys.excepthook, recorder)
  atexit.register(_exit_by_sigint, sys.excepthook)  # The first registered runs last, after the other exit handlers.
