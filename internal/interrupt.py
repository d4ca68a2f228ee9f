"""Ctrl-C (SIGINT) before a command finishes as one line, from the first statement of a script on.

It imports only the standard library, so a script sets it up before its other imports, which take seconds (jax,
orbax): Ctrl-C while they load prints the line that cli.run prints once main runs, instead of a traceback.
"""

import sys

MESSAGE = ('interrupted: stopped by Ctrl-C (SIGINT) before the command finished; what it wrote is kept, and the '
           'same command run again finishes the work')


def _one_line_hook(previous):
  """sys.excepthook printing MESSAGE for a KeyboardInterrupt that ends the process, previous for the rest."""
  def hook(kind, value, traceback):
    if issubclass(kind, KeyboardInterrupt):
      print(MESSAGE, file=sys.stderr)
    else:
      previous(kind, value, traceback)
  return hook


def one_line_when_run(module_name: str) -> None:
  """In a script run as a command (module_name '__main__'), a KeyboardInterrupt that ends the process prints
  MESSAGE; Python still exits as SIGINT stopped it (status 130 in a shell). Imported as a module: nothing."""
  if module_name == '__main__':
    sys.excepthook = _one_line_hook(sys.excepthook)
