"""A screenshot of a viewer's page in headless Chromium (Debian's `chromium`), through the DevTools protocol.

  python -m tools.view.screenshot http://127.0.0.1:8080 docs/viewer.png [--size 1200 800] [--timeout 300]

Opens the page, waits until its panel reports a full-size frame (the page is connected and the frame arrived), then
writes a PNG of the window. Chromium runs without a GPU (software WebGL), a sandbox or any network of its own, in a
new empty profile. Needs websockets (installed with viser).
"""

import argparse
import base64
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.request

CHROMIUM = 'chromium'
FLAGS = ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
         '--disable-background-networking', '--disable-component-update', '--disable-sync', '--hide-scrollbars',
         '--remote-debugging-port=0']
from internal import cli

SHOWN = '(full size)'  # What the panel says once a full-size frame was sent.
SETTLE = 2.            # Seconds the page stays as it is (no newer frame) before the screenshot.


class ScreenshotError(ValueError):
  """Chromium missing, not starting, or a page that never showed a frame; the message says which."""


class Page:
  """One page of a DevTools session: call(method, **params) -> its result."""

  def __init__(self, ws):
    self.ws, self.next_id = ws, 0

  def call(self, method: str, **params) -> dict:
    self.next_id += 1
    self.ws.send(json.dumps({'id': self.next_id, 'method': method, 'params': params}))
    while True:
      reply = json.loads(self.ws.recv(timeout=120))
      if reply.get('id') == self.next_id:
        if 'error' in reply:
          raise ScreenshotError(f'{CHROMIUM} refused {method}: {reply["error"]}')
        return reply['result']

  def text(self) -> str:
    """The page's visible text."""
    return self.call('Runtime.evaluate', expression='document.body.innerText', returnByValue=True)['result'].get(
        'value', '')


def devtools_port(proc, timeout: float) -> int:
  """The port of Chromium's DevTools, from the line it prints on start."""
  end = time.time() + timeout
  while time.time() < end:
    line = proc.stderr.readline()
    found = re.search(r'DevTools listening on ws://[^:]+:(\d+)/', line)
    if found:
      return int(found.group(1))
    if not line and proc.poll() is not None:
      break
  raise ScreenshotError(f'{CHROMIUM} did not start its DevTools (exit status {proc.poll()})')


def wait_for_rest(page: Page, deadline: float) -> str:
  """The page's text once it reports a full-size frame and has not changed for SETTLE seconds."""
  text, since = page.text(), time.time()
  while SHOWN not in text or time.time() - since < SETTLE:
    if time.time() > deadline:
      raise ScreenshotError(f'the page showed no full-size frame that stayed (--timeout); it says: {text[:200]!r}')
    time.sleep(.25)
    newer = page.text()
    if newer != text:
      text, since = newer, time.time()
  return text


def capture(url: str, size=(1200, 800), timeout: float = 300.) -> tuple:
  """(PNG bytes of the page at url once its panel reports a full-size frame, the page's text then)."""
  from websockets.sync.client import connect  # pylint: disable=import-outside-toplevel  (installed with viser)
  if shutil.which(CHROMIUM) is None:
    raise ScreenshotError(f'{CHROMIUM} is not installed (Debian: apt-get install chromium)')
  with tempfile.TemporaryDirectory() as profile:
    proc = subprocess.Popen([CHROMIUM, *FLAGS, f'--user-data-dir={profile}', f'--window-size={size[0]},{size[1]}',
                             'about:blank'], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
      port = devtools_port(proc, 60.)
      request = urllib.request.Request(f'http://127.0.0.1:{port}/json/new?about:blank', method='PUT')
      with urllib.request.urlopen(request, timeout=30) as response:
        target = json.load(response)
      with connect(target['webSocketDebuggerUrl'], max_size=None) as ws:
        page = Page(ws)
        page.call('Page.navigate', url=url)
        text = wait_for_rest(page, time.time() + timeout)
        return base64.b64decode(page.call('Page.captureScreenshot', format='png')['data']), text
    finally:
      proc.terminate()
      proc.wait(timeout=30)


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
  parser.add_argument('url')
  parser.add_argument('out', help='the PNG to write')
  parser.add_argument('--size', type=int, nargs=2, default=(1200, 800), metavar=('WIDTH', 'HEIGHT'))
  parser.add_argument('--timeout', type=float, default=300., help='seconds to wait for a full-size frame')
  args = parser.parse_args(argv)
  png, _ = capture(args.url, tuple(args.size), args.timeout)
  os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
  with open(args.out, 'wb') as f:
    f.write(png)
  print(f'{args.out}: the page at {args.url}')
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
