"""Screenshots of the view in a real headless Chromium (Debian's), driven by Playwright.

Chromium draws the viewer's WebGL with SwiftShader (software), so no GPU or display is
needed. Every request to a host other than this machine is refused: the view needs none
(the page itself asks for a web font, rerun's telemetry, its update check and examples
manifest; refused, they leave the view complete).
"""

import os
import time

import numpy as np

__all__ = ['screenshot', 'CHROMIUM', 'CHROMIUM_ARGS', 'MISSING', 'truth_drawn', 'green_surface']

CHROMIUM = '/usr/bin/chromium'
#: Headless, software WebGL (SwiftShader), nothing fetched in the background.
CHROMIUM_ARGS = ['--headless', '--no-sandbox', '--enable-unsafe-swiftshader',
                 '--use-angle=swiftshader', '--disable-background-networking',
                 '--disable-component-update', '--disable-sync', '--no-first-run',
                 '--disable-default-apps', '--mute-audio']
MISSING = (f'{CHROMIUM} is missing: apt-get install -y chromium; and pip install playwright '
           f'(Playwright drives that Chromium; it downloads no browser of its own here)')


def green_surface(img):
    """Pixels of a lit or shaded green surface (the truth box): a boolean (H, W) mask."""
    r, g, b = (img[..., k].astype(int) for k in range(3))
    return (g > 70) & (g > 1.5 * r + 10) & (g > 1.5 * b + 10)


def truth_drawn(img, least=1000):
    """Whether the truth box is drawn: at least ``least`` pixels of a green surface."""
    return int(green_surface(img).sum()) >= least


def _local(url):
    if url.startswith(('data:', 'blob:')):
        return True
    host = url.split('/')[2] if '//' in url else ''
    return host.rsplit(':', 1)[0].strip('[]') in ('127.0.0.1', 'localhost', '::1')


def screenshot(url, path, ready=truth_drawn, timeout=90.0, size=(1280, 720), settle=0.5):
    """Open ``url`` and screenshot it to ``path`` until the page is drawn.

    The page counts as drawn when two screenshots ``settle`` s apart are the same and
    ``ready(img)`` holds on them (``img`` an (H, W, 4) uint8 array; default
    :func:`truth_drawn`: the viewer's loading screen is still for seconds too).

    Returns
    -------
    img : numpy.ndarray
        The last screenshot.
    seconds : float
        From the browser's start to it.
    refused : list of str
        The URLs of other hosts the page asked for (refused).

    Raises
    ------
    RuntimeError
        Chromium is not installed, or the page was not drawn within ``timeout`` s.
    """
    if not os.path.exists(CHROMIUM):
        raise RuntimeError(MISSING)
    from PIL import Image
    from playwright.sync_api import sync_playwright
    refused = []

    def route(r):
        if _local(r.request.url):
            r.continue_()
        else:
            refused.append(r.request.url)
            r.abort()
    t0 = time.monotonic()
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={'width': size[0], 'height': size[1]})
            page.route('**/*', route)
            page.goto(url)
            img = prev = None
            while True:
                time.sleep(settle)
                page.screenshot(path=str(path))
                prev, img = img, np.asarray(Image.open(path).convert('RGBA'))
                if (prev is not None and np.array_equal(img, prev)
                        and (ready is None or ready(img))):
                    break
                if time.monotonic() - t0 > timeout:
                    raise RuntimeError(f'{url}: the page was not drawn in {timeout:g} s '
                                       f'(last screenshot: {path})')
        finally:
            browser.close()
    return img, time.monotonic() - t0, refused
