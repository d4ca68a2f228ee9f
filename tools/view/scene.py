"""The viewer's scene beside the render: the training cameras as frustums with their photos, the test cameras apart,
the render path through its frames' centres, and points (a cloud tools.points wrote, or a capture's own
structure-from-motion points); with camera refinement the given and the refined training cameras together, the
refined ones moving as newer checkpoints arrive. All in the world frame the first run trained in.
"""

import os

import numpy as np

from internal.cameras import algebra, alignment
from internal.datasets import capture as capture_loader
from internal.geometry import ply
from tools.view import cameras

# Each group of the scene: its colour (RGB) and whether it starts shown.
GROUPS = {'training cameras': ((40, 160, 60), True), 'given cameras': ((200, 60, 60), True),
          'test cameras': ((50, 110, 230), True), "compared run's training cameras": ((230, 150, 30), True),
          'render path': ((130, 130, 130), True), 'points': ((150, 150, 150), True)}
PHOTO_ROWS = 96        # Photos on the frustums are shown at most this tall.
FRUSTUM_SIZE = .08     # A frustum's depth, as a fraction of the scene's camera distance.
POINT_SIZE = .005      # A point's size, as a fraction of the scene's camera distance.


def frustum_poses(camera_set) -> list:
  """[(wxyz [4], position [3], fov, aspect)] of a runs.CameraSet, as viser places frustums."""
  height, width = camera_set.size
  return [(algebra.rotation_to_quaternion(c2w[:, :3]), c2w[:, 3], cameras.field_of_view(pixtocam, height),
           width / height) for c2w, pixtocam in zip(camera_set.camtoworlds, camera_set.pixtocams)]


def photo(image) -> np.ndarray:
  """uint8 [h, w, 3] of a float image [H, W, 3] in [0, 1], every k-th pixel so that h <= PHOTO_ROWS."""
  stride = -(-image.shape[0] // PHOTO_ROWS)
  return (np.clip(np.asarray(image[::stride, ::stride]), 0., 1.) * 255.).astype(np.uint8)


def add_frustums(server, group: str, camera_set, size: float, images=None) -> list:
  """Handles of one frustum a camera of camera_set, named /<group>/<k>, with its photo when images are given."""
  colour = GROUPS[group][0]
  return [server.scene.add_camera_frustum(f'/{group}/{k}', fov=fov, aspect=aspect, scale=size, color=colour,
                                          image=None if images is None else photo(images[k]), wxyz=wxyz,
                                          position=position)
          for k, (wxyz, position, fov, aspect) in enumerate(frustum_poses(camera_set))]


def move_frustums(handles: list, camera_set) -> None:
  """Moves frustums to the cameras of camera_set (the refined cameras of a newer checkpoint)."""
  for handle, (wxyz, position, _, _) in zip(handles, frustum_poses(camera_set)):
    handle.wxyz, handle.position = wxyz, position


def read_points(path: str, run) -> tuple:
  """(points [P,3], colours [P,3] uint8) to show: the PLY at path (tools.points' output), else a capture's
  structure-from-motion points (grey), else None; ValueError naming --points for a file that is not such a PLY."""
  if path:
    if not os.path.isfile(path):
      raise FileNotFoundError(f'--points {path!r} does not exist (tools.points writes a point cloud PLY)')
    try:
      points, colours, _ = ply.read_points(path)
    except (ValueError, KeyError, IndexError) as err:
      raise ValueError(f'--points {path!r} is not a point cloud PLY as tools.points writes ({err})') from err
    return points, colours
  if run.config.dataset_loader != 'capture':
    return None
  points = capture_loader.read_capture(run.config).points
  return points, np.full(points.shape, GROUPS['points'][0][0], np.uint8)


def scene_distance(run) -> float:
  """The distance of a camera from the middle of the scene (the unit the scene's objects are sized by)."""
  return alignment.camera_distance(run.train_set.camtoworlds, run.space)


def draw(server, runs: list, points) -> dict:
  """{group: [scene handles]} of the scene of runs[0] (and the training cameras of runs[1] where its views
  differ); points: read_points' (points, colours) or None."""
  first = runs[0]
  size = FRUSTUM_SIZE * scene_distance(first)
  sets = first.training_cameras()
  groups = {'training cameras': add_frustums(server, 'training cameras', sets.get('refined', sets['given']), size,
                                             first.train_set.images)}
  if 'refined' in sets:
    groups['given cameras'] = add_frustums(server, 'given cameras', sets['given'], size)
  groups['test cameras'] = add_frustums(server, 'test cameras', first.test_cameras(), size)
  if len(runs) > 1 and list(runs[1].train_set.ids) != list(first.train_set.ids):
    other = runs[1].training_cameras()
    groups["compared run's training cameras"] = add_frustums(
        server, "compared run's training cameras", other.get('refined', other['given']), size)
  groups['render path'] = [server.scene.add_spline_catmull_rom('/render path', first.path_centres(),
                                                               color=GROUPS['render path'][0], line_width=2.)]
  if points is not None:
    groups['points'] = [server.scene.add_point_cloud('/points', np.asarray(points[0], np.float32), points[1],
                                                     point_size=POINT_SIZE * scene_distance(first))]
  return groups


def up_direction(run) -> np.ndarray:
  """[3] the training cameras' mean up direction (-y of OpenCV axes): the viewer's up."""
  up = -run.training_cameras()['given'].camtoworlds[:, :, 1].mean(0)
  return up / np.linalg.norm(up)
