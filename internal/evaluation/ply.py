"""Binary PLY meshes (little endian): float32 vertex positions, uchar colours, triangles; written atomically."""

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


def read(path: str) -> tuple:
  """(vertices [V, 3] f32, faces [F, 3] int, colours [V, 3] uint8) of a PLY written by write."""
  with open(path, 'rb') as f:
    data = f.read()
  end = data.index(b'end_header\n') + len(b'end_header\n')
  header = data[:end].decode('ascii').split('\n')
  counts = {line.split()[1]: int(line.split()[2]) for line in header if line.startswith('element')}
  vertex = np.frombuffer(data, VERTEX, counts['vertex'], end)
  face = np.frombuffer(data, FACE, counts['face'], end + counts['vertex'] * VERTEX.itemsize)
  verts = np.stack([vertex[n] for n in 'xyz'], -1)
  return verts, face['vertex_indices'].astype(np.int64), np.stack([vertex[n] for n in ('red', 'green', 'blue')], -1)
