"""Rays of corrected cameras against the loaders' own ray builders, their gradients against finite differences,
the seeded camera noise and the similarity alignment of cameras."""

import gin
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conftest import SHARED_DATA
from internal import config_loader
from internal import configs
from internal.cameras import algebra, alignment, caster, corrections
from internal.cameras.records import Cameras, Pixels, RaySpace
from internal.datasets import load_dataset
from internal.rays import Rays

H, W = 6, 8
FOCAL = 7.
OMEGA, SHIFT = np.array([.03, -.05, .02]), np.array([.1, -.05, .08])


def _camera(seed: int) -> np.ndarray:
  """A [3,4] camera 4 units from the origin looking at it (OpenGL axes)."""
  rng = np.random.default_rng(seed)
  position = rng.normal(size=3)
  position = 4. * position / np.linalg.norm(position)
  return algebra.viewmatrix(position, np.array([0., 0., 1.]), position)


def _forward_camera(seed: int) -> np.ndarray:
  """A [3,4] forward-facing camera near the origin looking down -z (LLFF's frame)."""
  rng = np.random.default_rng(seed)
  return np.concatenate([Rotation.from_rotvec(rng.normal(size=3) * .05).as_matrix(),
                         rng.normal(size=(3, 1)) * .1], 1)


PIXTOCAM = algebra.focal_pixtocam(FOCAL, H, W)
# A COLMAP camera of the same size with a phone's distortion (its pinhole part is PIXTOCAM's).
DISTORTION = np.array([FOCAL, FOCAL, W / 2, H / 2, -.12, .03, 1e-3, -5e-4])
# (camera, RaySpace, distortion or None): every kind of rays a loader makes.
KINDS = {
    'pinhole': (_camera, RaySpace(opengl=True, near=2., far=6., height=H, width=W), None),
    'dtu': (_camera, RaySpace(opengl=False, near=.5, far=3.5, height=H, width=W, plane_z=.3), None),
    'ndc': (_forward_camera, RaySpace(opengl=True, near=0., far=1., height=H, width=W, ndc_focal=FOCAL), None),
    'capture_ndc': (_forward_camera, RaySpace(opengl=False, near=0., far=1., height=H, width=W, ndc_focal=FOCAL),
                    DISTORTION),
}


def _cameras(c2w, distortion_params) -> Cameras:
  """One camera c2w [3,4] of PIXTOCAM (and COLMAP's distortion_params [8] or None)."""
  return Cameras(c2w[None], PIXTOCAM[None], None if distortion_params is None else distortion_params[None])


def _rays(kind: str, c2w) -> Rays:
  """The loaders' rays [H,W,...] of the camera c2w of kind."""
  _, space, distortion_params = KINDS[kind]
  return Rays(*[x[0] for x in caster.image_rays(_cameras(c2w, distortion_params), space)])


def _corrected(kind: str, omega, shift, xp=np):
  """(rays [1,H,W,...] of the camera of kind corrected by (omega, shift) with cameras/corrections.py, the camera)."""
  make_camera, space, distortion_params = KINDS[kind]
  c2w = make_camera(0)
  rays = Rays(*[xp.asarray(np.asarray(x[None], np.float64)) for x in _rays(kind, c2w)])
  image = caster.image_pixels(0, H, W)
  pixels = Pixels(np.zeros((1, 1, 1), int), image.x[None], image.y[None])
  at = lambda x: xp.asarray(x)[None, None, None]
  moved = corrections.corrected_rays(rays, at(corrections.so3_exp(omega, xp)), at(c2w[:, 3]), at(shift), space, xp,
                                     _cameras(c2w, distortion_params), pixels)
  return moved, c2w


@pytest.mark.parametrize('kind', KINDS)
def test_corrected_rays_are_the_loaders_rays_of_the_corrected_camera(kind):
  rays, c2w = _corrected(kind, OMEGA, SHIFT)
  moved = corrections.corrected_cameras(c2w[None], Rotation.from_rotvec(OMEGA).as_matrix()[None], SHIFT[None])
  expected = _rays(kind, moved[0])
  for name, got, want in zip(rays._fields, rays, expected):
    np.testing.assert_allclose(np.asarray(got)[0], want, rtol=2e-6, atol=2e-6, err_msg=name)
  unmoved, _ = _corrected(kind, np.zeros(3), np.zeros(3))
  for got, want in zip(unmoved, _rays(kind, c2w)):
    np.testing.assert_allclose(np.asarray(got)[0], want, rtol=2e-6, atol=2e-6)


@pytest.mark.parametrize('kind', KINDS)
def test_the_step_corrects_rays_in_float32_as_numpy_does_in_float64(kind):
  """Inside the step (jax.numpy, float32) the corrected rays are those of numpy's float64 arithmetic, the NDC
  neighbours cast from the cameras (COLMAP's distortion inverted by jax.numpy too)."""
  want, _ = _corrected(kind, OMEGA, SHIFT)
  got, _ = jax.jit(lambda omega, shift: _corrected(kind, omega, shift, jnp))(OMEGA.astype(np.float32),
                                                                            SHIFT.astype(np.float32))
  for name, a, b in zip(want._fields, got, want):
    np.testing.assert_allclose(np.asarray(a), b, rtol=2e-5, atol=2e-5, err_msg=name)


@pytest.mark.parametrize('kind', KINDS)
def test_gradients_through_the_corrected_rays_match_finite_differences(kind):
  weights = [np.random.default_rng(i).normal(size=(1, H, W, x)) for i, x in enumerate((3, 3, 3, 1))]

  def value(params):  # A scalar of every field the corrections move: origins, directions, viewdirs, radii.
    rays, _ = _corrected(kind, params[:3], params[3:], jnp)
    return sum(jnp.sum(w * x) for w, x in zip(weights, rays[:4]))

  with jax.enable_x64(True):
    at = jnp.asarray(np.concatenate([OMEGA, SHIFT]))
    value = jax.jit(value)
    grad = np.asarray(jax.grad(value)(at))
    eps = 1e-6
    numeric = np.array([(value(at + eps * e) - value(at - eps * e)) / (2 * eps) for e in np.eye(6)])
    zero = np.asarray(jax.grad(value)(jnp.zeros(6)))  # The start of refinement: no NaN from the angle's norm.
  np.testing.assert_allclose(grad, numeric, rtol=1e-6, atol=1e-6)
  assert np.all(np.isfinite(zero)) and np.any(zero != 0)


def test_so3_exp_is_rodrigues_and_exact_near_zero():
  omega = np.array([[.3, -1.2, .5], [1e-5, 2e-5, -1e-5], [0., 0., 0.], [0., 0., np.pi - 1e-3]])
  np.testing.assert_allclose(corrections.so3_exp(omega), Rotation.from_rotvec(omega).as_matrix(), atol=1e-14)
  np.testing.assert_allclose(np.rad2deg(alignment.rotation_angle(corrections.so3_exp(omega))),
                             np.rad2deg(np.linalg.norm(omega, axis=-1)), atol=1e-5)


# ------------------------------------------------------------------ noise on the training cameras

def _generated(scene_dir, rig='object', *bindings):
  gin.clear_config()
  return config_loader.load_config(['configs/demo.gin'], [
      f"Config.data_dir = '{scene_dir}_{rig}'", f"Config.generated_rig = '{rig}'", 'Config.generated_size = (32, 40)',
      *bindings])


NOISE = ('Config.camera_noise_rotation_deg = 5.', 'Config.camera_noise_translation = 0.05')


@pytest.mark.parametrize('rig', ['object', 'forward'])
def test_noise_turns_and_moves_each_training_camera_exactly_and_its_rays_follow(scene_dir, rig):
  clean_config = _generated(scene_dir, rig)
  clean = load_dataset('train', clean_config)
  noisy = load_dataset('train', _generated(scene_dir, rig, *NOISE))
  angles = np.rad2deg(alignment.rotation_angle(
      np.swapaxes(clean.camtoworlds[:, :, :3], 1, 2) @ noisy.camtoworlds[:, :, :3]))
  np.testing.assert_allclose(angles, 5., atol=2e-3)
  distance = 2. if rig == 'forward' else 4.  # (near + far) / 2 = (2 + 6) / 2; NDC: alignment.NDC_DISTANCE.
  np.testing.assert_allclose(np.linalg.norm(noisy.camtoworlds[:, :, 3] - clean.camtoworlds[:, :, 3], axis=-1),
                             .05 * distance, rtol=1e-5)
  assert noisy.space == clean.space and bool(clean.space.ndc_focal) == (rig == 'forward')
  # The rays are the loader's rays of the noisy cameras.
  expected = caster.image_rays(Cameras(noisy.camtoworlds.astype(np.float64), clean.pixtocams), clean.space)
  for name, got, want in zip(expected._fields, noisy.rays, expected):
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5, err_msg=name)


@pytest.mark.parametrize('views,seed,aligned', [(6, 0, 4.50), (6, 1, 4.81), (3, 1, 2.29)])
def test_a_similarity_explains_part_of_random_turns_which_errors_without_it_read_whole(scene_dir, views, seed,
                                                                                      aligned):
  """Cameras each turned by exactly 5 degrees about random axes and moved by 5% read less after the similarity
  (the median over the views; the fewer the views the less), exactly that without it (the generated scene's frame
  is the reference's): a baseline must be measured under the same alignment, never assumed."""
  clean = load_dataset('train', _generated(scene_dir, 'object', f'Config.n_input_views = {views}'))
  noisy = load_dataset('train', _generated(scene_dir, 'object', *NOISE, f'Config.n_input_views = {views}',
                                           f'Config.camera_noise_seed = {seed}'))
  distance = alignment.camera_distance(clean.camtoworlds, clean.space)
  whole = alignment.errors(noisy.camtoworlds, clean.camtoworlds, distance, align=False)
  np.testing.assert_allclose(whole['rotation_deg'], 5., atol=2e-3)
  np.testing.assert_allclose(whole['translation'], .05, rtol=1e-5)
  after = alignment.errors(noisy.camtoworlds, clean.camtoworlds, distance)
  assert np.median(after['rotation_deg']) == pytest.approx(aligned, abs=.01)


def test_noise_is_seeded_per_view_and_leaves_the_test_cameras(scene_dir):
  noisy = load_dataset('train', _generated(scene_dir, 'object', *NOISE))
  again = load_dataset('train', _generated(scene_dir, 'object', *NOISE))
  other = load_dataset('train', _generated(scene_dir, 'object', *NOISE, 'Config.camera_noise_seed = 1'))
  fewer = load_dataset('train', _generated(scene_dir, 'object', *NOISE, 'Config.n_input_views = 3'))
  np.testing.assert_array_equal(noisy.camtoworlds, again.camtoworlds)
  assert not np.allclose(noisy.camtoworlds, other.camtoworlds)
  shared = [noisy.ids.index(i) for i in fewer.ids]  # A view's noise does not depend on the other views.
  np.testing.assert_array_equal(fewer.camtoworlds, noisy.camtoworlds[shared])
  clean_test = load_dataset('test', _generated(scene_dir, 'object'))
  noisy_test = load_dataset('test', _generated(scene_dir, 'object', *NOISE))
  for name in ('camtoworlds', 'images'):
    np.testing.assert_array_equal(getattr(clean_test, name), getattr(noisy_test, name))
  for a, b in zip(clean_test.rays, noisy_test.rays):
    np.testing.assert_array_equal(a, b)


def _min_pairwise_angle(directions: np.ndarray) -> float:
  """The smallest angle (degrees) between two of directions [N,3] (unit vectors)."""
  cosines = np.clip(directions @ directions.T, -1., 1.)[np.triu_indices(len(directions), 1)]
  return float(np.rad2deg(np.arccos(cosines)).min())


def test_each_view_draws_its_own_noise(scene_dir):
  # One draw shared by every view is a rigid motion of the rig, which a similarity mostly explains: the evaluation's
  # camera error caught it only narrowly (0.987 degrees against a bound of 1).
  clean = load_dataset('train', _generated(scene_dir, 'object'))
  noisy = load_dataset('train', _generated(scene_dir, 'object', *NOISE))
  turns = np.asarray(noisy.camtoworlds[:, :, :3], np.float64) @ np.swapaxes(clean.camtoworlds[:, :, :3], 1, 2)
  axes = Rotation.from_matrix(turns).as_rotvec()
  shifts = np.asarray(noisy.camtoworlds[:, :, 3], np.float64) - clean.camtoworlds[:, :, 3]
  for directions in (axes, shifts):  # One shared draw: 0 degrees apart and a mean direction of length 1.
    directions = directions / np.linalg.norm(directions, axis=-1, keepdims=True)
    assert _min_pairwise_angle(directions) > 5.  # Measured: 15.5 (axes) and 14.5 degrees (shifts), 8 views.
    assert np.linalg.norm(directions.mean(0)) < .7  # Measured: 0.41 and 0.42.


def test_noise_that_moves_the_cameras_beyond_float32_is_refused_naming_it(scene_dir):
  config = _generated(scene_dir, 'object', 'Config.camera_noise_translation = 1e38')  # Itself within float32.
  with pytest.raises(ValueError, match=r"^Config.camera_noise_translation = 1e\+38 moves the training cameras by "
                     r"4e\+38 \(x the camera distance 4\), beyond float32's range"):
    load_dataset('train', config)
  load_dataset('train', _generated(scene_dir, 'object', 'Config.camera_noise_translation = 1e37'))


@pytest.mark.skipif(not (SHARED_DATA / 'llff' / 'fern').is_dir(), reason='../shared/data/llff/fern is absent')
def test_an_llff_scene_carries_the_ndc_focal_its_loader_cast_its_rays_with():
  gin.clear_config()
  config = config_loader.load_config(['configs/mini/llff3_freenerf.gin'],
                                     [f"Config.data_dir = '{SHARED_DATA / 'llff'}'", "Config.llff_scan = 'fern'"])
  data = load_dataset('train', config)
  assert data.space.ndc_focal == pytest.approx(1. / data.pixtocams[0, 0, 0], rel=1e-6)
  rays = caster.image_rays(Cameras(data.camtoworlds[:1], data.pixtocams[:1]), data.space)
  for name, got, want in zip(rays._fields, rays, data.rays):
    np.testing.assert_allclose(got[0], want[0], rtol=1e-4, atol=1e-5, err_msg=name)


# ------------------------------------------------------------------ the similarity between sets of cameras

def _random_cameras(n: int, seed: int) -> np.ndarray:
  return np.stack([_camera(seed + i) for i in range(n)])


@pytest.mark.parametrize('n', [1, 2, 6])
def test_fit_recovers_a_similarity_and_leaves_no_error(n):
  source = _random_cameras(n, 10)
  truth = alignment.Similarity(1.7, Rotation.from_rotvec([.4, -.3, 1.1]).as_matrix(), np.array([1., 2., -3.]))
  target = truth.cameras(source)
  fit = alignment.fit(source, target)
  np.testing.assert_allclose(fit.rotation, truth.rotation, atol=1e-10)
  np.testing.assert_allclose(fit.cameras(source), target, atol=1e-10)
  if n > 1:
    assert fit.scale == pytest.approx(1.7)
  errors = alignment.errors(source, target, 4.)
  np.testing.assert_allclose(errors['rotation_deg'], 0., atol=1e-5)
  np.testing.assert_allclose(errors['translation'], 0., atol=1e-10)


def test_errors_measure_one_disturbed_camera_among_many():
  reference = _random_cameras(12, 20)
  disturbed = reference.copy()
  disturbed[3, :, :3] = Rotation.from_rotvec([0., np.deg2rad(2.), 0.]).as_matrix() @ reference[3, :, :3]
  disturbed[3, :, 3] += np.array([0., .04, 0.])
  moved = alignment.Similarity(2., Rotation.from_rotvec([.2, .1, 0.]).as_matrix(), np.ones(3))
  errors = alignment.errors(moved.cameras(disturbed), reference, 4.)
  assert errors['rotation_deg'][3] == pytest.approx(2., abs=.25)
  assert errors['translation'][3] == pytest.approx(.01, abs=.002)
  assert np.median(errors['rotation_deg']) < .2


# ------------------------------------------------------------------ every loader's rays follow the noisy cameras

def _real(loader_name: str, **kw):
  """A Config of a shared real scene, or None when it is absent."""
  found = {'llff': (SHARED_DATA / 'llff' / 'fern', dict(dataset_loader='llff', data_dir=str(SHARED_DATA / 'llff'),
                                                         llff_scan='fern', factor=8, near=0., far=1.)),
           'dtu': (SHARED_DATA / 'dtu' / 'dtu_scan24', dict(dataset_loader='dtu', data_dir=str(SHARED_DATA / 'dtu'),
                                                            dtu_scan='dtu_scan24', factor=4, near=.5, far=3.5,
                                                            near_origin=.1, white_background=False,
                                                            allow_missing_test_views=True)),
           'blender': (SHARED_DATA / 'blender' / 'lego', dict(dataset_loader='blender',
                                                              data_dir=str(SHARED_DATA / 'blender'), factor=8)),
           'capture': (SHARED_DATA / 'colmap' / 'cup', dict(dataset_loader='capture',
                                                           data_dir=str(SHARED_DATA / 'colmap' / 'cup'), factor=4,
                                                           white_background=False))}[loader_name]
  if not found[0].is_dir():
    pytest.skip(f'{found[0]} is absent')
  return configs.Config(n_input_views=3, **found[1], **kw)


@pytest.mark.parametrize('name', ['llff', 'dtu', 'blender', 'capture'])
def test_every_loaders_rays_follow_its_noisy_cameras(name):
  clean = load_dataset('train', _real(name))
  noisy = load_dataset('train', _real(name, camera_noise_rotation_deg=5., camera_noise_translation=.05))
  turn = noisy.camtoworlds[:, :, :3].astype(np.float64) @ np.swapaxes(clean.camtoworlds[:, :, :3], 1, 2)
  np.testing.assert_allclose(np.rad2deg(alignment.rotation_angle(turn)), 5., atol=2e-3)
  world = noisy.rays.viewdirs  # NDC rays keep the world directions there; world rays' viewdirs are unit directions.
  np.testing.assert_allclose(world, np.einsum('nij,nhwj->nhwi', turn, clean.rays.viewdirs), atol=2e-5)
  space = clean.space
  if name == 'llff':  # The loader's NDC rays of the noisy cameras.
    expected = Rays(*[x[0] for x in caster.image_rays(Cameras(noisy.camtoworlds[:1].astype(np.float64),
                                                               clean.pixtocams[:1]), space)])
    for field, got, want in zip(expected._fields, noisy.rays, expected):
      np.testing.assert_allclose(got[0], want, rtol=1e-4, atol=2e-5, err_msg=field)
  elif name == 'dtu':
    assert space.plane_z == .1
    np.testing.assert_allclose(noisy.rays.origins[..., 2], .1, atol=1e-5)
  else:
    np.testing.assert_allclose(noisy.rays.origins, np.broadcast_to(noisy.camtoworlds[:, None, None, :, 3],
                                                                   noisy.rays.origins.shape), atol=1e-5)
  kept = ('lossmult', 'near', 'far') + (() if name == 'llff' else ('radii',))  # Rotations keep world radii.
  for field in kept:
    np.testing.assert_allclose(getattr(noisy.rays, field), getattr(clean.rays, field), rtol=1e-5, atol=1e-7)
