// The guidance picture of docs/guidance.md (web/screenshots/guidance.jpg): the shipped guided
// recording (`tests/sessions/guided-slide.mcap`: a loose hand aiming 6 mm beside the expert's
// slide, pulled toward it at full gain) replayed, frozen mid-slide, the camera close on the tool:
// the expert's path ahead and behind, the ghost of the expert's tool, the green guiding force
// beside the blue total, and the guidance row in the panel.
//
//   npm run screenshot:guide    (builds and starts the server as the browser tests do;
//                                SOFTHAPTIC_BIN to reuse a built one)
//
// The picture is a JPEG kept under 150 KB (the script says its size, and fails above it).
import { statSync } from 'node:fs';
import { fileURLToPath } from 'node:url';

import { launchBrowser } from './browser.mjs';
import { startServer } from './server.mjs';

const PICTURE = fileURLToPath(new URL('../screenshots/guidance.jpg', import.meta.url));
const RECORDING = fileURLToPath(new URL('../../tests/sessions/guided-slide.mcap', import.meta.url));
const MAX_BYTES = 150 * 1024;
const WAIT = { timeout: 120000 };

const browser = await launchBrowser();
try {
  const server = await startServer({ command: ['replay', RECORDING], external: false });
  try {
    const page = await browser.newPage({ viewport: { width: 1280, height: 800 } });
    await page.goto(server.url);
    await page.waitForFunction(() => window.__softhaptic?.ready(), null, WAIT);
    // Mid-slide: engaged, pulling, the tool pressed in.
    await page.waitForFunction(
      () => {
        const g = window.__softhaptic.guide();
        return g.ghostVisible && g.engaged && g.arrowLengthM > 0.007 && window.__softhaptic.contact().inContact;
      },
      null,
      WAIT,
    );
    await page.evaluate(() => window.__softhaptic.pause(true));
    const ghost = await page.evaluate(() => window.__softhaptic.guide().ghostPosition);
    await page.evaluate((p) => window.__softhaptic.focusCamera(p, 0.13, 0.4), ghost);
    // Two frames for the moved camera and the panel's next refresh.
    await page.waitForTimeout(600);
    await page.screenshot({ path: PICTURE, type: 'jpeg', quality: 70 });
    const bytes = statSync(PICTURE).size;
    console.log(`${PICTURE}: ${(bytes / 1024).toFixed(0)} KB`);
    if (bytes > MAX_BYTES) {
      console.error(`larger than ${MAX_BYTES / 1024} KB: lower the quality or the size`);
      process.exitCode = 1;
    }
  } finally {
    await server.stop();
  }
} finally {
  await browser.close();
}
