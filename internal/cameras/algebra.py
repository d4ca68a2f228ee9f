"""Camera algebra: rotations as quaternions, look-at matrices, projection decomposition, pose
recentering/rescaling, render paths."""

import numpy as np
from scipy.spatial import transform as spatial_transform


def normalize(x: np.ndarray) -> np.ndarray:
  """Unit vectors along the last axis of x [...,3]."""
  return x / np.linalg.norm(x, axis=-1, keepdims=True)


def quaternion_to_rotation(wxyz) -> np.ndarray:
  """[3,3] rotation of a quaternion (w, x, y, z) [4], normalized first."""
  w, x, y, z = np.asarray(wxyz, np.float64) / np.linalg.norm(wxyz)
  return np.array([[1. - 2. * (y * y + z * z), 2. * (x * y - w * z), 2. * (x * z + w * y)],
                   [2. * (x * y + w * z), 1. - 2. * (x * x + z * z), 2. * (y * z - w * x)],
                   [2. * (x * z - w * y), 2. * (y * z + w * x), 1. - 2. * (x * x + y * y)]])


def rotation_to_quaternion(rotation) -> np.ndarray:
  """[4] unit quaternion (w, x, y, z) with w >= 0 of a rotation [3,3]: scipy's, which starts from the largest of
  the four components (Shepperd's choice; stable at any angle, a half turn included) and normalizes."""
  x, y, z, w = spatial_transform.Rotation.from_matrix(np.asarray(rotation, np.float64)).as_quat()
  wxyz = np.array([w, x, y, z])
  return -wxyz if w < 0 else wxyz


def viewmatrix(lookdir: np.ndarray, up: np.ndarray, position: np.ndarray) -> np.ndarray:
  """[3,4] pose whose z axis is along lookdir [3], y near up [3], centred at position [3]."""
  vec2 = normalize(lookdir)
  vec0 = normalize(np.cross(up, vec2))
  vec1 = normalize(np.cross(vec2, vec0))
  return np.stack([vec0, vec1, vec2, position], axis=1)


def poses_avg(poses: np.ndarray) -> np.ndarray:
  """[3,4] average pose of poses [N,3,4]: mean centre, mean z axis, mean y axis as up."""
  return viewmatrix(poses[:, :3, 2].mean(0), poses[:, :3, 1].mean(0), poses[:, :3, 3].mean(0))


def to_homogeneous(poses: np.ndarray) -> np.ndarray:
  """[...,3,4] -> [...,4,4] with bottom row (0,0,0,1)."""
  bottom = np.broadcast_to(np.array([0., 0., 0., 1.]), poses.shape[:-2] + (1, 4))
  return np.concatenate([poses[..., :3, :4], bottom], axis=-2)


def recenter_poses(poses: np.ndarray) -> np.ndarray:
  """[N,3,4] poses left-multiplied by the inverse of their average pose."""
  return (np.linalg.inv(to_homogeneous(poses_avg(poses))) @ to_homogeneous(poses))[:, :3, :4]


def rescale_poses(poses: np.ndarray) -> np.ndarray:
  """[N,3,4] poses with all translations divided by s = max |t_xyz|."""
  out = poses.copy()
  out[:, :3, 3] /= np.abs(poses[:, :3, 3]).max()
  return out


def rq3(matrix: np.ndarray) -> tuple:
  """RQ decomposition of [3,3] M = R Q with R upper triangular with positive diagonal and Q orthogonal."""
  flip = np.eye(3)[::-1]
  q_t, r_t = np.linalg.qr((flip @ matrix).T)
  upper, ortho = flip @ r_t.T @ flip, flip @ q_t.T
  signs = np.diag(np.sign(np.diag(upper)))
  return upper @ signs, signs @ ortho


def decompose_projection(proj: np.ndarray) -> tuple:
  """P [3,4] -> (K [3,3] with K[2,2] = 1 and positive diagonal, R [3,3] world-to-camera, C [3] centre)."""
  proj = np.asarray(proj, np.float64)[:3, :4]
  if np.linalg.det(proj[:, :3]) < 0:
    proj = -proj  # The same camera; makes R a proper rotation, as cv2 gives for DTU's P.
  intrinsics, rotation = rq3(proj[:, :3])
  centre = -np.linalg.solve(proj[:, :3], proj[:, 3])
  return intrinsics / intrinsics[2, 2], rotation, centre


def projection_to_camtoworld(proj: np.ndarray) -> tuple:
  """P [3,4] -> (K [3,3], c2w [3,4] = [R^T | C]) in OpenCV axes (x right, y down, z forward)."""
  intrinsics, rotation, centre = decompose_projection(proj)
  return intrinsics, np.concatenate([rotation.T, centre[:, None]], axis=1)


def scale_intrinsics(intrinsics: np.ndarray, factor: float) -> np.ndarray:
  """K [...,3,3] for images downsampled by factor: diag(1/f, 1/f, 1) K (no half-pixel shift)."""
  return np.diag([1. / factor, 1. / factor, 1.]) @ intrinsics


def focal_pixtocam(focal: float, height: int, width: int) -> np.ndarray:
  """[3,3] inverse intrinsics of a centred pinhole with focal length focal (pixels)."""
  return np.array([[1. / focal, 0., -0.5 * width / focal],
                   [0., 1. / focal, -0.5 * height / focal],
                   [0., 0., 1.]])


def focus_point(poses: np.ndarray) -> np.ndarray:
  """[3] least-squares point nearest to the optical (z) axes of poses [N,3,4]."""
  dirs, origins = poses[:, :3, 2:3], poses[:, :3, 3:4]
  proj = np.eye(3) - dirs * np.transpose(dirs, [0, 2, 1])
  mt_m = np.transpose(proj, [0, 2, 1]) @ proj
  return np.linalg.solve(mt_m.mean(0), (mt_m @ origins).mean(0))[:, 0]


def spiral_positions(poses: np.ndarray, perc: float, n_frames: int, n_rots: int, zrate: float) -> np.ndarray:
  """[F,3] camera centres of a spiral in the frame of the average of poses [N,3,4].

  Radii: the perc-th percentile of |translation| per axis; n_rots turns, the depth oscillating at zrate.
  """
  radii = np.concatenate([np.percentile(np.abs(poses[:, :3, 3]), perc, 0), [1.]])
  c2w = to_homogeneous(poses_avg(poses))
  thetas = np.linspace(0., 2. * np.pi * n_rots, n_frames, endpoint=False)
  return np.stack([(c2w @ (np.array([np.cos(t), -np.sin(t), -np.sin(t * zrate), 1.]) * radii))[:3]
                   for t in thetas])


def spiral_path_llff(poses: np.ndarray, bounds: np.ndarray, n_frames: int, n_rots: int = 2,
                     zrate: float = .5) -> np.ndarray:
  """[F,3,4] LLFF spiral around the average of poses [N,3,4] (OpenGL), focused from scene bounds [N,2]."""
  focal = 1. / ((1. - .75) / (bounds.min() * .9) + .75 / (bounds.max() * 5.))
  target = (to_homogeneous(poses_avg(poses)) @ np.array([0., 0., -focal, 1.]))[:3]
  up = poses[:, :3, 1].mean(0)
  return np.stack([viewmatrix(position - target, up, position)
                   for position in spiral_positions(poses, 90, n_frames, n_rots, zrate)])


def spiral_path_dtu(poses: np.ndarray, n_frames: int, n_rots: int = 2, zrate: float = .5,
                    perc: float = 60) -> np.ndarray:
  """[F,3,4] DTU spiral (OpenCV, +z towards the focus point of poses [N,3,4])."""
  centre, up = focus_point(poses), poses[:, :3, 1].mean(0)
  return np.stack([viewmatrix(centre - position, up, position)
                   for position in spiral_positions(poses, perc, n_frames, n_rots, zrate)])


def orbit_path(poses: np.ndarray, n_frames: int) -> np.ndarray:
  """[F,3,4] OpenGL cameras circling the world z axis at the mean radius/height of poses, facing the origin."""
  centres = poses[:, :3, 3]
  radius = np.linalg.norm(centres[:, :2], axis=-1).mean()
  height = centres[:, 2].mean()
  out = []
  for theta in np.linspace(0., 2. * np.pi, n_frames, endpoint=False):
    position = np.array([radius * np.cos(theta), radius * np.sin(theta), height])
    out.append(viewmatrix(position, np.array([0., 0., 1.]), position))
  return np.stack(out)
