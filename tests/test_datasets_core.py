"""Data-free tests of the dataset machinery: downsampling, cameras, rays, splits and batching."""

import numpy as np
import pytest
from PIL import Image

from internal.configs import Config
from internal.cameras import algebra, caster
from internal.cameras.records import Cameras, RaySpace
from internal.datasets import base, blender, dtu, image_io, llff
from internal.datasets.batching import make_batcher
from internal.rays import Rays


def random_image(h, w, c=3, seed=0):
  return np.random.default_rng(seed).random((h, w, c)).astype(np.float32)


def random_rotation(rng):
  q, r = np.linalg.qr(rng.normal(size=(3, 3)))
  q = q * np.sign(np.diag(r))
  return q if np.linalg.det(q) > 0 else -q


# ---------------------------------------------------------------- downsampling

def test_released_factor4_is_mean_of_centre_2x2():
  img = random_image(16, 24)
  out = image_io.downsample(img, 4, 'released')
  assert out.shape == (4, 6, 3) and out.dtype == np.float32
  np.testing.assert_allclose(out[0, 0], img[1:3, 1:3].mean((0, 1)), rtol=1e-6)
  expected = (img[1::4, 1::4] + img[2::4, 1::4] + img[1::4, 2::4] + img[2::4, 2::4]) / 4.
  np.testing.assert_allclose(out, expected, rtol=1e-5, atol=1e-7)


def test_released_odd_factor_is_centre_pixel_and_factor8_centre_pair():
  img = random_image(15, 21, seed=1)
  np.testing.assert_allclose(image_io.downsample(img, 3, 'released'), img[1::3, 1::3], atol=1e-7)
  img = random_image(16, 24, seed=2)
  expected = (img[3::8, 3::8] + img[4::8, 3::8] + img[3::8, 4::8] + img[4::8, 4::8]) / 4.
  np.testing.assert_allclose(image_io.downsample(img, 8, 'released'), expected, rtol=1e-5, atol=1e-7)


def test_released_factor2_equals_block_mean():
  img = random_image(8, 10, seed=3)
  np.testing.assert_allclose(image_io.downsample(img, 2, 'released'),
                             img.reshape(4, 2, 5, 2, 3).mean((1, 3)), rtol=1e-5, atol=1e-7)


def test_released_non_divisible_matches_separable_interp():
  """cv2 INTER_LINEAR: sample at (x+.5)*src/dst-.5, edge-clamped; np.interp is an independent 1-D version."""
  img = random_image(10, 7, c=2, seed=4)
  out = image_io.downsample(img, 3, 'released')
  assert out.shape == (3, 2, 2)
  rows = (np.arange(3) + .5) * 10 / 3 - .5
  cols = (np.arange(2) + .5) * 7 / 2 - .5
  tmp = np.zeros((3, 7, 2))
  for j in range(7):
    for c in range(2):
      tmp[:, j, c] = np.interp(rows, np.arange(10), img[:, j, c])
  expected = np.zeros((3, 2, 2))
  for i in range(3):
    for c in range(2):
      expected[i, :, c] = np.interp(cols, np.arange(7), tmp[i, :, c])
  np.testing.assert_allclose(out, expected, rtol=1e-5, atol=1e-6)


def test_area_mode_matches_pil_box_filter():
  img = random_image(12, 16, seed=5)
  out = image_io.downsample(img, 4, 'area')
  np.testing.assert_allclose(out[0, 0], img[:4, :4].mean((0, 1)), rtol=1e-6)
  for c in range(3):
    box = Image.fromarray(img[..., c], mode='F').resize((4, 3), Image.BOX)
    np.testing.assert_allclose(out[..., c], np.asarray(box), rtol=1e-5, atol=1e-6)


def test_area_mode_rejects_non_divisible_and_unknown_mode():
  with pytest.raises(base.DatasetError, match='divisible'):
    image_io.downsample(random_image(10, 8), 4, 'area')
  with pytest.raises(base.DatasetError, match='downsample_mode'):
    image_io.downsample(random_image(8, 8), 2, 'nearest')


def test_binary_mask_released_values(tmp_path):
  """== 255 per channel (anti-aliased edges -> background), then released bilinear: quarter steps."""
  png = np.zeros((8, 8, 3), np.uint8)
  png[:, :3] = 255
  png[:2, 3] = 254
  png[5:, 5] = 255
  Image.fromarray(png).save(tmp_path / 'm.png')
  mask = image_io.load_binary_mask(str(tmp_path / 'm.png'), 4, 'released')
  binary = (png == 255).astype(np.float32)
  expected = (binary[1::4, 1::4] + binary[2::4, 1::4] + binary[1::4, 2::4] + binary[2::4, 2::4]) / 4.
  np.testing.assert_allclose(mask, expected)
  assert set(np.unique(mask)) <= {0., .25, .5, .75, 1.} and mask.shape == (2, 2, 3)


# ---------------------------------------------------------------- cameras

@pytest.mark.parametrize('seed,sign', [(0, 1.), (1, -1.), (2, 3.7)])
def test_decompose_projection_recovers_k_r_c(seed, sign):
  rng = np.random.default_rng(seed)
  k = np.array([[rng.uniform(500, 3000), rng.uniform(-5, 5), rng.uniform(100, 900)],
                [0., rng.uniform(500, 3000), rng.uniform(100, 700)], [0., 0., 1.]])
  rot, centre = random_rotation(rng), rng.normal(size=3) * 100.
  proj = sign * k @ np.concatenate([rot, -rot @ centre[:, None]], 1)
  k_out, rot_out, centre_out = algebra.decompose_projection(proj)
  np.testing.assert_allclose(k_out, k, rtol=1e-9, atol=1e-9)
  np.testing.assert_allclose(rot_out, rot, atol=1e-12)
  np.testing.assert_allclose(centre_out, centre, rtol=1e-9)
  _, c2w = algebra.projection_to_camtoworld(proj)
  np.testing.assert_allclose(c2w, np.concatenate([rot.T, centre[:, None]], 1), atol=1e-9)


def test_rq3_properties():
  m = np.random.default_rng(3).normal(size=(3, 3))
  r, q = algebra.rq3(m)
  np.testing.assert_allclose(r @ q, m, atol=1e-12)
  np.testing.assert_allclose(q @ q.T, np.eye(3), atol=1e-12)
  assert np.allclose(np.tril(r, -1), 0.) and (np.diag(r) > 0).all()


@pytest.mark.parametrize('seed', range(6))
def test_a_rotation_survives_its_quaternion(seed):
  rotation = random_rotation(np.random.default_rng(seed))
  q = algebra.rotation_to_quaternion(rotation)
  assert q[0] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-12
  np.testing.assert_allclose(algebra.quaternion_to_rotation(q), rotation, atol=1e-14)


@pytest.mark.parametrize('angle', [0., np.pi / 2, np.pi, 3.])
def test_quaternions_of_known_turns_about_z_including_a_half_turn(angle):
  c, s = np.cos(angle), np.sin(angle)
  rotation = np.array([[c, -s, 0.], [s, c, 0.], [0., 0., 1.]])
  np.testing.assert_allclose(algebra.rotation_to_quaternion(rotation), [np.cos(angle / 2), 0., 0., np.sin(angle / 2)],
                             atol=1e-15)


def test_the_quaternion_of_a_float32_rotation_is_a_unit_one():
  """Cameras are kept in float32, a little off orthogonal: their quaternions (viser's frustums, COLMAP's files) are
  still of unit length."""
  rng = np.random.default_rng(7)
  for _ in range(50):
    q = algebra.rotation_to_quaternion(random_rotation(rng).astype(np.float32))
    assert abs(np.linalg.norm(q) - 1.) < 1e-15


def test_recenter_and_rescale():
  rng = np.random.default_rng(4)
  poses = np.stack([np.concatenate([random_rotation(rng), rng.normal(size=(3, 1)) * 5.], 1) for _ in range(7)])
  centred = algebra.recenter_poses(poses)
  np.testing.assert_allclose(algebra.poses_avg(centred), np.eye(3, 4), atol=1e-12)
  relative = lambda p: np.linalg.inv(algebra.to_homogeneous(p[0])) @ algebra.to_homogeneous(p)
  np.testing.assert_allclose(relative(centred), relative(poses), atol=1e-9)   # A rigid change of world frame.
  scaled = algebra.rescale_poses(centred)
  assert np.isclose(np.abs(scaled[:, :, 3]).max(), 1.)
  np.testing.assert_allclose(scaled[:, :, 3] * np.abs(centred[:, :, 3]).max(), centred[:, :, 3])
  np.testing.assert_allclose(scaled[:, :, :3], centred[:, :, :3])


def test_focus_point_and_dtu_spiral_look_at_it():
  rng = np.random.default_rng(5)
  target = np.array([.3, -.2, 1.5])
  positions = rng.normal(size=(9, 3)) * 2.
  poses = np.stack([algebra.viewmatrix(target - p, np.array([0., -1., 0.]), p) for p in positions])
  np.testing.assert_allclose(algebra.focus_point(poses), target, atol=1e-9)
  path = algebra.spiral_path_dtu(poses, 12)
  assert path.shape == (12, 3, 4)
  to_target = algebra.normalize(target - path[:, :, 3])
  np.testing.assert_allclose(path[:, :, 2], to_target, atol=1e-9)
  np.testing.assert_allclose(path[:, :, :3].transpose(0, 2, 1) @ path[:, :, :3], np.broadcast_to(np.eye(3),
                                                                                                  (12, 3, 3)),
                             atol=1e-12)


def test_llff_spiral_faces_focal_point():
  rng = np.random.default_rng(6)
  poses = np.stack([np.concatenate([np.eye(3), rng.normal(size=(3, 1)) * .1], 1) for _ in range(5)])
  poses = algebra.recenter_poses(poses)
  bounds = np.array([[1.5, 10.], [2., 12.]])
  path = algebra.spiral_path_llff(poses, bounds, 240)
  focal = 1. / (.25 / (1.5 * .9) + .75 / (12. * 5.))
  focus = np.array([0., 0., -focal])  # The average pose is the identity after recentering.
  assert path.shape == (240, 3, 4)
  np.testing.assert_allclose(path[:, :, 2], algebra.normalize(path[:, :, 3] - focus), atol=1e-9)


# ---------------------------------------------------------------- rays

def camera_rays(c2w, pixtocam, space: RaySpace) -> Rays:
  """Rays [H,W,...] of one camera in space (caster.image_rays)."""
  return Rays(*[x[0] for x in caster.image_rays(Cameras(np.asarray(c2w)[None], np.asarray(pixtocam)[None]), space)])


def test_pinhole_rays_opengl_closed_form():
  h, w, f = 4, 6, 5.
  c2w = np.concatenate([np.eye(3), [[1.], [2.], [3.]]], 1)
  rays = camera_rays(c2w, algebra.focal_pixtocam(f, h, w), RaySpace(opengl=True, near=2., far=6., height=h, width=w))
  x, y = np.meshgrid(np.arange(w), np.arange(h))
  expected = np.stack([(x + .5 - w / 2) / f, -(y + .5 - h / 2) / f, -np.ones_like(x, float)], -1)
  np.testing.assert_allclose(rays.directions, expected, atol=1e-6)
  np.testing.assert_allclose(rays.origins, np.broadcast_to([1., 2., 3.], (h, w, 3)))
  np.testing.assert_allclose(np.linalg.norm(rays.viewdirs, axis=-1), 1., atol=1e-6)
  np.testing.assert_allclose(rays.radii, 1. / f * 2. / np.sqrt(12.), rtol=1e-6)
  assert all(x.dtype == np.float32 for x in rays)
  assert (rays.lossmult == 1).all() and (rays.near == 2).all() and (rays.far == 6).all()
  assert rays.radii.shape == rays.near.shape == (h, w, 1)


def test_pinhole_rays_at_integer_pixel_coordinates_of_a_rotated_camera():
  """pixel_offset 0: the released Blender code's R ((i - W/2)/f, -(j - H/2)/f, -1), by hand for two pixels."""
  rotation = np.array([[0., 0., 1.], [0., 1., 0.], [-1., 0., 0.]])  # 90 degrees about y: camera -z is world -x.
  c2w = np.concatenate([rotation, [[0.], [0.], [4.]]], 1)
  rays = camera_rays(c2w, algebra.focal_pixtocam(2., 4, 4),
                     RaySpace(opengl=True, near=2., far=6., height=4, width=4, pixel_offset=0.))
  # Pixel (i, j) = (0, 0): camera (-1, 1, -1) -> world (-1, 1, 1); the principal point (2, 2): (0, 0, -1) -> -x.
  np.testing.assert_allclose(rays.directions[0, 0], [-1., 1., 1.], atol=1e-6)
  np.testing.assert_allclose(rays.directions[2, 2], [-1., 0., 0.], atol=1e-6)


@pytest.mark.parametrize('released', [True, False])
@pytest.mark.parametrize('height,width', [(3, 4), (2, 5)])
def test_radii_neighbours_as_released_on_images_and_the_next_pixel_on_patches(released, height, width):
  """An image's last row (column) takes the second-to-last distance again, as the released code's (a single
  distance is repeated); RegNeRF's patches take the next pixel's everywhere."""
  space = RaySpace(opengl=True, near=2., far=6., height=height, width=width, released_edges=released)
  cameras = Cameras(np.eye(3, 4)[None], np.eye(3)[None])  # Camera direction of pixel (x, y): (x + .5, -y - .5, -1).
  pixels = caster.image_pixels(0, height, width)
  for axis, position, length in ((caster.ROW, pixels.y, height), (caster.COLUMN, pixels.x, width)):
    ends = caster.neighbour_directions(cameras, pixels, space, axis, np)
    coordinate = np.abs(ends[..., 1 - axis]) - .5  # The pixel row (column) of each end.
    first = np.where((position < length - 1) | (not released), position, max(length - 3, 0))
    np.testing.assert_array_equal(coordinate, np.stack([first, first + 1], -1))


def test_dtu_rays_shifted_onto_plane_on_the_same_line():
  rng = np.random.default_rng(7)
  c2w = np.concatenate([random_rotation(rng), [[.2], [.1], [-1.]]], 1)
  c2w[:, 2] = np.sign(c2w[2, 2]) * c2w[:, 2]  # Cameras look towards +z world ...
  c2w[:, 0] = np.cross(c2w[:, 1], c2w[:, 2])  # ... keeping a proper rotation.
  pixtocam = np.linalg.inv(np.array([[30., 0., 8.], [0., 30., 6.], [0., 0., 1.]]))
  rays = camera_rays(c2w, pixtocam, RaySpace(opengl=False, near=.5, far=3.5, height=12, width=16, plane_z=0.))
  np.testing.assert_allclose(rays.origins[..., 2], 0., atol=1e-6)
  offset = rays.origins - c2w[:, 3]
  np.testing.assert_allclose(np.cross(offset, rays.directions), 0., atol=1e-5)
  cam = rays.directions @ c2w[:, :3]
  np.testing.assert_allclose(cam[..., 2], 1., atol=1e-6)   # OpenCV camera, z = +1.
  np.testing.assert_allclose(cam[0, 0, :2], (np.array([.5, .5]) - [8., 6.]) / 30., atol=1e-6)


def test_ndc_closed_form_for_identity_camera():
  h, w, f = 4, 6, 3.
  rays = camera_rays(np.eye(3, 4), algebra.focal_pixtocam(f, h, w),
                     RaySpace(opengl=True, near=0., far=1., height=h, width=w, ndc_focal=f))
  np.testing.assert_allclose(rays.origins[..., 2], -1., atol=1e-6)
  x = np.arange(w) + .5 - w / 2
  np.testing.assert_allclose(rays.origins[0, :, 0], 2. * x / w, atol=1e-6)
  np.testing.assert_allclose(rays.directions[..., 2], 2., atol=1e-6)
  np.testing.assert_allclose(rays.directions[..., :2], 0., atol=1e-6)  # Camera at the origin: d' = (0, 0, 2).
  np.testing.assert_allclose(rays.radii, .5 * (2. / h + 2. / w) * 2. / np.sqrt(12.), rtol=1e-5)
  assert (np.linalg.norm(rays.viewdirs, axis=-1) >= 1.).all()  # World directions, not normalised.
  assert (rays.near == 0).all() and (rays.far == 1).all()


# ---------------------------------------------------------------- splits

def test_llff_split_table_half_to_even():
  table = {3: [1, 10, 19], 6: [1, 4, 7, 12, 15, 19], 9: [1, 3, 5, 7, 10, 12, 14, 17, 19]}
  for n, ids in table.items():
    assert llff.split_ids('train', 20, 8, n) == ids
  assert llff.split_ids('test', 20, 8, 99) == [0, 8, 16]
  assert llff.split_ids('train', 34, 8, 9) == [1, 5, 9, 12, 17, 21, 25, 28, 33]   # flower, with two ties.
  assert llff.split_ids('train', 62, 8, 3) == [1, 30, 61]                         # horns tie.
  assert llff.split_ids('train', 62, 8, 9) == [1, 9, 15, 23, 30, 38, 46, 53, 61]
  assert llff.split_ids('train', 26, 8, 3) == [1, 12, 25]                         # leaves tie.
  assert llff.split_ids('train', 25, 8, 9) == [1, 3, 6, 10, 12, 14, 18, 21, 23]   # orchids.
  assert llff.split_ids('train', 41, 8, 9) == [1, 5, 10, 15, 20, 25, 30, 35, 39]  # room.
  assert llff.split_ids('train', 55, 8, 6) == [1, 11, 22, 33, 44, 54]             # trex.
  assert llff.split_ids('train', 20, 8, 0) == [i for i in range(20) if i % 8]       # 0 = all views.


def test_dtu_split_ids():
  train, test = dtu.split_ids('pixelnerf', 49, 8)
  assert train[:3] == [25, 22, 28] and train[:6] == [25, 22, 28, 40, 44, 48] and len(test) == 25
  assert not set(train) & set(test) and not (set(train) | set(test)) & set(dtu.EXCLUDED_IDS)
  assert set(train) | set(test) | set(dtu.EXCLUDED_IDS) == set(range(49))
  train, test = dtu.split_ids('dtuhold', 49, 8)
  assert test == list(range(0, 49, 8)) and len(train) == 42
  assert dtu.split_ids('depth_eval', 49, 8) == (train, test)   # The released mip-NeRF 'all' config's name.
  assert dtu.split_ids('all', 49, 8) == (list(range(49)), list(range(49)))
  with pytest.raises(base.DatasetError, match='dtu_split_type'):
    dtu.split_ids('pixelnerf_reduced', 49, 8)


def test_blender_frame_ids():
  assert blender.frame_ids('train', 100, 'dietnerf', 8, 8) == [26, 86, 2, 55, 75, 93, 16, 73]
  assert blender.frame_ids('train', 100, 'first_n', 3, 8) == [0, 1, 2]
  assert blender.frame_ids('test', 200, 'dietnerf', 8, 8) == list(range(0, 200, 8))
  with pytest.raises(base.DatasetError, match='n_input_views = 9'):
    blender.frame_ids('train', 100, 'dietnerf', 9, 8)


# ---------------------------------------------------------------- batching

def encoded_dataset(n=3, h=4, w=5):
  """A Dataset whose rgb and every ray field encode (image, row, column) of the pixel."""
  grid = np.stack(np.meshgrid(np.arange(n), np.arange(h), np.arange(w), indexing='ij'), -1).astype(np.float32)
  one = grid[..., :1]
  rays = Rays(grid, grid + 1, grid + 2, one, one, one, one)
  return base.Dataset(images=grid / 10., camtoworlds=np.zeros((n, 3, 4)), pixtocams=np.zeros((n, 3, 3)),
                      ids=list(range(n)), height=h, width=w, near=0., far=1., masks=None, rays=rays,
                      split='train', name='encoded')


@pytest.mark.parametrize('mode', ['single_image', 'all_images'])
def test_batcher_shapes_correspondence_and_reproducibility(mode):
  data = encoded_dataset()
  config = Config(batching=mode, batch_size=512, np_rng_seed=11)
  batch = make_batcher(data, config)(7)
  assert isinstance(batch.rays, Rays) and all(x is None for x in batch[2:])  # No other family asked for.
  assert batch.rgb.shape == (512, 3) and batch.rgb.dtype == np.float32
  for field in batch.rays:
    assert field.shape[0] == 512 and field.dtype == np.float32
  np.testing.assert_allclose(batch.rays.origins, batch.rgb * 10., atol=1e-5)
  np.testing.assert_allclose(batch.rays.viewdirs, batch.rgb * 10. + 2, atol=1e-5)
  again = make_batcher(data, config)(7)
  np.testing.assert_array_equal(again.rgb, batch.rgb)
  assert not np.array_equal(make_batcher(data, config)(8).rgb, batch.rgb)
  other_seed = Config(batching=mode, batch_size=512, np_rng_seed=12)
  assert not np.array_equal(make_batcher(data, other_seed)(7).rgb, batch.rgb)
  images = np.unique(batch.rays.origins[:, 0])
  pixels = np.unique(batch.rays.origins.reshape(-1, 3), axis=0)
  if mode == 'single_image':
    assert images.size == 1 and images[0] == np.random.default_rng([11, 7]).integers(3)
    assert len(pixels) == 20   # 512 draws with replacement cover all 20 pixels of the image.
  else:
    assert images.size == 3 and len(pixels) == 60


def test_batcher_unknown_mode():
  with pytest.raises(base.DatasetError, match='batching'):
    make_batcher(encoded_dataset(), Config(batching='by_ray'))
