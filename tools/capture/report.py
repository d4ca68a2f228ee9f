"""What the report flags: cameras out of order along the capture, a capture split into several models, images
registered on few points, photos left out. A low reprojection error does not make the cameras right (structure-from-
motion can fold the circle of cameras around a symmetric object at 0.6 px), so these are the checks it can make;
cameras.png is the one to look at.

Order: along the capture (the photos' name order, a video's time order) each camera should be near the previous one
and move on the same way along the arc. A *jump* is a step longer than JUMP_STEPS median steps (and JUMP_MIN of the
camera distance); a *turn* is a run of steps back against the capture's direction covering more than TURN_STEPS
median steps. Both are expected of photos taken in several passes; in one sweep (a video) they point to folded
cameras.
"""

from typing import Dict, List

import numpy as np

JUMP_STEPS, JUMP_MIN = 4., .15
TURN_STEPS = 3.
FEW_POINTS = .25  # An image registered on fewer 3D points than this fraction of the median is flagged.


def arc_coordinate(c2w: np.ndarray, forward: bool) -> np.ndarray:
  """[N] position of each camera [N, 3, 4] (loader frame) along the capture: the unwrapped azimuth about +z in
  camera distances (inward), or the position along the centres' widest spread (forward)."""
  centres = c2w[:, :, 3]
  if forward:
    flat = centres - centres.mean(0)
    return flat @ np.linalg.svd(flat, full_matrices=False)[2][0]
  azimuth = np.unwrap(np.arctan2(centres[:, 1], centres[:, 0]))
  return azimuth * np.median(np.linalg.norm(centres[:, :2], axis=-1))


def order_problems(c2w: np.ndarray, forward: bool, names: List[str]) -> Dict[str, List[str]]:
  """{'jumps': ['a -> b', ...], 'turns': ['at a', ...]} of the cameras c2w [N, 3, 4] taken in the order given,
  named by names [N]."""
  if len(names) < 3:
    return {'jumps': [], 'turns': []}
  steps = np.linalg.norm(np.diff(c2w[:, :, 3], axis=0), axis=-1)
  along = np.diff(arc_coordinate(c2w, forward))
  median = float(np.median(steps))
  jumping = steps > max(JUMP_STEPS * median, JUMP_MIN)
  direction = np.sign(np.sum(along[~jumping])) or 1.
  backward = [bool(not jumping[i] and step * direction < 0) for i, step in enumerate(along)] + [False]
  turns, run, start = [], 0., None
  for i, back in enumerate(backward):  # The closing False ends a run still open at the last step.
    if back:
      run, start = run + abs(along[i]), i if start is None else start
    else:
      if start is not None and run > TURN_STEPS * median:
        turns.append(f'at {names[start]}')
      run, start = 0., None
  return {'jumps': [f'{names[i]} -> {names[i + 1]}' for i in np.flatnonzero(jumping)], 'turns': turns}


def flags(report: dict, order: Dict[str, List[str]], observations: Dict[str, int], video: bool) -> List[dict]:
  """The report's flags [{'check', 'images', 'message'}]: what the cameras' picture should be checked for."""
  found = []
  if report['unregistered']:
    found.append({'check': 'unregistered', 'images': report['unregistered'], 'message':
                  f'{len(report["unregistered"])} of {report["photos"]} images are not in the model: '
                  f'{listed(report["unregistered"])} (too little overlap with the others, blur, or plain surfaces)'})
  apart = report['left_in_other_models']
  if apart:
    found.append({'check': 'models', 'images': apart, 'message':
                  f'structure-from-motion split the capture into {len(report["models"])} models of '
                  f'{report["models"]} images: sparse/0 is the largest, {len(apart)} images are only in the others '
                  f'(sfm/models/): {listed(apart)}; photos between the parts would join them'})
  median = float(np.median(list(observations.values())))
  few = sorted((n for n, count in observations.items() if count < FEW_POINTS * median), key=observations.get)
  if few:
    chosen = [f'{n} ({split})' for split, names in report['views'].items() for n in names if n in few]
    found.append({'check': 'few_points', 'images': few, 'message':
                  f'{len(few)} images are registered on few points (under {FEW_POINTS:.0%} of the median '
                  f'{median:.0f}): {listed([f"{n} ({observations[n]})" for n in few])}; their cameras are the '
                  'least certain' + (f', and among the default views: {", ".join(chosen)} (choose others with '
                                     'Config.train_view_ids / test_view_ids if its camera is off in cameras.png)'
                                     if chosen else '')})
  if order['jumps'] or order['turns']:
    found.append({'check': 'order', 'images': [], 'message':
                  f'the cameras are out of order along the capture: the path jumps {len(order["jumps"])} times '
                  f'({listed(order["jumps"])}) and turns back {len(order["turns"])} times ({listed(order["turns"])}); '
                  + ('a video is one sweep, so the cameras may be folded' if video else
                     'expected of photos taken in several passes or out of name order; if you took them in one '
                     'sweep, the cameras may be folded') + ': look at cameras.png'})
  return found


def listed(items: List[str], shown: int = 5) -> str:
  """The first few items joined, with how many more."""
  return ', '.join(items[:shown]) + (f' and {len(items) - shown} more' if len(items) > shown else '') or 'none'


def summary(report: dict) -> str:
  """The printed summary of a report: registration, model, rig and views, timings, flags, picture."""
  reg, error = report['registered'], report['reprojection_error_px']
  lines = [f'{report["out"]}: {reg} of {report["photos"]} images registered, {report["points"]} points, mean '
           f'reprojection error {error:.2f} px (structure-from-motion at {report["sfm_long_side"]} px)',
           f'  trains as: {report["rig"]} rig; {len(report["views"]["train"])} training views '
           f'({", ".join(report["views"]["train"])}), {len(report["views"]["test"])} test views '
           f'({listed(report["views"]["test"])})',
           '  seconds: ' + ', '.join(f'{k} {v:.1f}' for k, v in report['seconds'].items())
           + (f' (mapping run {report["mapping_attempts"]} times: the first left images out)'
              if report.get('mapping_attempts', 1) > 1 else '')]
  lines += [f'  check: {f["message"]}' for f in report['flags']] or ['  check: nothing flagged']
  lines.append(f'  picture: {report["picture"]} (cameras and points from above and from the side)')
  return '\n'.join(lines)
