"""Binary PLY files (little endian), written atomically: meshes (float32 vertex positions, uchar colours, triangles)
and point clouds (positions, optional normals, colours)."""

import numpy as np

from internal import atomic

VERTEX = np.dtype([('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('red', 'u1'), ('green', 'u1'), ('blue', 'u1')])
FACE = np.dtype([('count', 'u1'), ('vertex_indices', '<i4', (3,))])


def encode(verts, faces, colours) -> bytes:
  """PLY bytes of vertices [V, 3], triangles [F, 3] (indices into them) and colours [V, 3] in [0, 1]."""
  header = ('ply\nformat binary_little_endian 1.0\ncomment FreeNeRF-JAX tools.mesh\n'
            f'element vertex {len(verts)}\nproperty float x\nproperty float y\nproperty float z\n'
            'property uchar red\nproperty uchar green\nproperty uchar blue\n'
            f'element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n')
  vertex = np.empty(len(verts), VERTEX)
  for i, name in enumerate('xyz'):
    vertex[name] = verts[:, i]
  for i, name in enumerate(('red', 'green', 'blue')):
    vertex[name] = np.round(np.clip(colours[:, i], 0., 1.) * 255.)
  face = np.empty(len(faces), FACE)
  face['count'], face['vertex_indices'] = 3, faces
  return header.encode('ascii') + vertex.tobytes() + face.tobytes()


def write(path: str, verts, faces, colours) -> None:
  """Writes the mesh to path (atomically: a reader never sees a partial file)."""
  atomic.write_bytes(path, encode(verts, faces, colours))


def _read(path: str) -> tuple:
  """(bytes, header lines, offset of the body, {element: count}) of a PLY file."""
  with open(path, 'rb') as f:
    data = f.read()
  end = data.index(b'end_header\n') + len(b'end_header\n')
  header = data[:end].decode('ascii').split('\n')
  return data, header, end, {line.split()[1]: int(line.split()[2]) for line in header if line.startswith('element')}


def read(path: str) -> tuple:
  """(vertices [V, 3] f32, faces [F, 3] int, colours [V, 3] uint8) of a PLY written by write."""
  data, _, end, counts = _read(path)
  vertex = np.frombuffer(data, VERTEX, counts['vertex'], end)
  face = np.frombuffer(data, FACE, counts['face'], end + counts['vertex'] * VERTEX.itemsize)
  verts = np.stack([vertex[n] for n in 'xyz'], -1)
  return verts, face['vertex_indices'].astype(np.int64), np.stack([vertex[n] for n in ('red', 'green', 'blue')], -1)


def _point_dtype(normals: bool) -> np.dtype:
  """The vertex record of a point cloud: x y z, nx ny nz when normals, red green blue."""
  fields = [('x', '<f4'), ('y', '<f4'), ('z', '<f4')] + (
      [('nx', '<f4'), ('ny', '<f4'), ('nz', '<f4')] if normals else []) + [('red', 'u1'), ('green', 'u1'),
                                                                           ('blue', 'u1')]
  return np.dtype(fields)


def encode_points(points, colours, normals=None) -> bytes:
  """PLY bytes of a point cloud: points [P, 3], colours [P, 3] in [0, 1], optional unit normals [P, 3]."""
  dtype = _point_dtype(normals is not None)
  properties = ''.join(f'property {"float" if dtype[name].kind == "f" else "uchar"} {name}\n' for name in dtype.names)
  header = (f'ply\nformat binary_little_endian 1.0\ncomment FreeNeRF-JAX tools.points\nelement vertex {len(points)}\n'
            f'{properties}end_header\n')
  vertex = np.empty(len(points), dtype)
  for i, name in enumerate('xyz'):
    vertex[name] = points[:, i]
  if normals is not None:
    for i, name in enumerate(('nx', 'ny', 'nz')):
      vertex[name] = normals[:, i]
  for i, name in enumerate(('red', 'green', 'blue')):
    vertex[name] = np.round(np.clip(colours[:, i], 0., 1.) * 255.)
  return header.encode('ascii') + vertex.tobytes()


def write_points(path: str, points, colours, normals=None) -> None:
  """Writes a point cloud to path (atomically)."""
  atomic.write_bytes(path, encode_points(points, colours, normals))


def read_points(path: str) -> tuple:
  """(points [P, 3] f32, colours [P, 3] uint8, normals [P, 3] f32 or None) of a PLY written by write_points."""
  data, header, end, counts = _read(path)
  has_normals = 'property float nx' in header
  vertex = np.frombuffer(data, _point_dtype(has_normals), counts['vertex'], end)
  stack = lambda names: np.stack([vertex[n] for n in names], -1)
  return stack('xyz'), stack(('red', 'green', 'blue')), stack(('nx', 'ny', 'nz')) if has_normals else None
