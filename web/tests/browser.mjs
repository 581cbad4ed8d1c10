// Launching the system's Chromium for the browser tests and the benchmark (playwright-core
// drives it; no browser is downloaded). WebGL runs on SwiftShader, so no GPU is needed.
import { existsSync } from 'node:fs';
import { chromium } from 'playwright-core';

/** Chromium from the environment (CHROMIUM=path) or Debian's package. */
export function chromiumPath() {
  const candidates = [process.env.CHROMIUM, '/usr/bin/chromium', '/usr/bin/chromium-browser'].filter(Boolean);
  const found = candidates.find((p) => existsSync(p));
  if (!found) {
    throw new Error(`no Chromium found (tried ${candidates.join(', ')}); install it with: apt-get install -y chromium`);
  }
  return found;
}

/** Headless Chromium; `extraArgs` are added to the command line (e.g. to switch WebGL off). */
export async function launchBrowser({ extraArgs = [] } = {}) {
  return chromium.launch({
    executablePath: chromiumPath(),
    args: [
      '--headless',
      '--no-sandbox',
      '--disable-gpu',
      '--disable-background-networking',
      '--use-angle=swiftshader',
      '--enable-unsafe-swiftshader',
      '--ignore-gpu-blocklist',
      ...extraArgs,
    ],
  });
}
