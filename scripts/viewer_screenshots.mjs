// Screenshots of the lostx web viewer in headless Chromium, in the light and the dark theme.
//
//   node scripts/viewer_screenshots.mjs URL OUT_PREFIX WIDTHxHEIGHT [WIDTHxHEIGHT ...]
//
// Writes OUT_PREFIX-light-WxH.png and OUT_PREFIX-dark-WxH.png. Each is taken in a fresh
// browser profile once the page has stopped changing (the viewer decodes the recording's
// images in software here, which takes a while), with the pointer parked where no tooltip
// can appear. Prints every request the page tries to make to another host (there should
// be none: lostx serves the page with a policy that keeps it on this machine).
import { mkdtempSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { chromium } from 'playwright-core';

const [url, prefix, ...sizes] = process.argv.slice(2);
if (!url || !prefix || sizes.length === 0) {
  console.error('usage: node scripts/viewer_screenshots.mjs URL OUT_PREFIX WIDTHxHEIGHT [WIDTHxHEIGHT ...]');
  process.exit(2);
}
const executablePath = process.env.CHROMIUM || '/usr/bin/chromium';
// No GPU here: WebGL runs on SwiftShader, which Chromium only allows when asked to.
const args = ['--no-sandbox', '--disable-gpu', '--disable-background-networking', '--disable-component-update',
  '--no-first-run', '--disable-sync', '--use-angle=swiftshader', '--enable-unsafe-swiftshader'];
const settleMs = 3000;
const maxWaitMs = 180000;

async function shoot(theme, width, height) {
  const profile = mkdtempSync(join(tmpdir(), 'lostx-chromium-'));
  const context = await chromium.launchPersistentContext(profile, {
    executablePath, headless: true, args, viewport: { width, height }, colorScheme: theme,
  });
  try {
    const page = context.pages()[0] || await context.newPage();
    page.on('request', (request) => {
      const host = new URL(request.url()).hostname;
      if (!['127.0.0.1', 'localhost', '[::1]'].includes(host)) console.log(`outside request: ${request.url()}`);
    });
    await page.goto(url);
    await page.mouse.move(width - 2, 2);
    // Below the top bar, whose latency figure keeps changing.
    const clip = { x: 0, y: 40, width, height: height - 40 };
    const start = Date.now();
    let previous = null;
    for (;;) {
      await page.waitForTimeout(settleMs);
      const current = await page.screenshot({ clip });
      if (previous !== null && current.equals(previous)) break;
      if (Date.now() - start > maxWaitMs) {
        console.log(`${theme} ${width}x${height}: still changing after ${maxWaitMs / 1000} s; taking it anyway`);
        break;
      }
      previous = current;
    }
    const out = `${prefix}-${theme}-${width}x${height}.png`;
    await page.screenshot({ path: out });
    console.log(`wrote ${out} (${Math.round((Date.now() - start) / 1000)} s)`);
  } finally {
    await context.close();
    rmSync(profile, { recursive: true, force: true });
  }
}

for (const size of sizes) {
  const [width, height] = size.split('x').map(Number);
  for (const theme of ['light', 'dark']) await shoot(theme, width, height);
}
