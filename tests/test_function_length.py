"""Short functions: no function of the house's code (internal/, tools/, bench/, lab/, the scripts) spans over 50
lines, from its `def` to its last line, docstring and nested functions included."""

import ast
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1]
HOUSE = ('internal', 'tools', 'bench', 'lab')
LIMIT = 50


def long_functions(path: pathlib.Path, limit: int = LIMIT) -> list:
  """'file:line name (N lines)' of each function of a file that spans over limit lines."""
  found = []
  for node in ast.walk(ast.parse(path.read_text(), str(path))):
    if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
      lines = node.end_lineno - node.lineno + 1
      if lines > limit:
        found.append(f'{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}:{node.lineno} {node.name} '
                     f'({lines} lines)')
  return found


def test_long_functions_counts_every_line_of_a_function_nested_ones_too(tmp_path):
  path = tmp_path / 'm.py'
  body = ''.join(f'  x{i} = {i}\n' for i in range(49))
  path.write_text(f'def fits():\n{body}\ndef outer():\n  def inner():\n{body.replace("  ", "    ")}  return inner\n')
  assert long_functions(path) == [f'{path}:52 outer (52 lines)']
  assert long_functions(path, 49) == [f'{path}:1 fits (50 lines)', f'{path}:52 outer (52 lines)',
                                      f'{path}:53 inner (50 lines)']


def test_no_function_of_the_house_is_over_50_lines():
  paths = [p for folder in HOUSE for p in sorted((ROOT / folder).rglob('*.py'))] + sorted(ROOT.glob('*.py'))
  assert len(paths) > 100 and ROOT / 'tools' / 'points.py' in paths
  assert not [f for p in paths for f in long_functions(p)]
