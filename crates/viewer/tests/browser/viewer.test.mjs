// Browser test of the semrecon viewer page: Debian's chromium, headless, driven by
// playwright-core. Checks that the page loads, the mesh is drawn, class colours appear in
// the "classes" mode, and a click throws a ball that moves.
//
// usage: node viewer.test.mjs URL SCREENSHOT_DIR [--static]
//   URL: http://127.0.0.1:PORT/ of `semrecon view`, or file:///.../index.html of
//   `semrecon export-viewer` (--static: the ball is a replayed precomputed throw).
// Exit status 0 when every check passes; messages say which check failed.

import { mkdirSync } from 'node:fs';
import { join } from 'node:path';
import { chromium } from 'playwright-core';

const [url, outDir, flag] = process.argv.slice(2);
if (!url || !outDir) {
  console.error('usage: node viewer.test.mjs URL SCREENSHOT_DIR [--static]');
  process.exit(2);
}
const isStatic = flag === '--static';
const executablePath = process.env.CHROMIUM || '/usr/bin/chromium';
mkdirSync(outDir, { recursive: true });

const failures = [];
function check(ok, message) {
  console.log(`${ok ? 'ok  ' : 'FAIL'} ${message}`);
  if (!ok) failures.push(message);
}

const browser = await chromium.launch({
  executablePath,
  headless: true,
  args: [
    '--headless',
    '--no-sandbox',
    '--disable-gpu',
    '--disable-background-networking',
    '--disable-component-update',
    '--disable-sync',
    '--no-first-run',
    // WebGL without a GPU: chromium's software rasteriser, which it no longer picks by itself.
    '--enable-unsafe-swiftshader',
    '--use-angle=swiftshader',
  ],
});
try {
  const page = await browser.newPage({ viewport: { width: 1100, height: 720 } });
  const consoleErrors = [];
  page.on('console', (m) => { if (m.type() === 'error') consoleErrors.push(m.text()); });
  page.on('pageerror', (e) => consoleErrors.push(String(e)));

  await page.goto(url);
  await page.waitForFunction(() => window.viewerState && (window.viewerState.ready || window.viewerState.error), null, { timeout: 60000 });
  const loaded = await page.evaluate(() => ({ ...window.viewerState }));
  check(loaded.ready && !loaded.error, `page loaded (${loaded.triangles} triangles, labelled ${loaded.labelled}) ${loaded.error || ''}`);
  await page.waitForFunction(() => window.viewerState.frames > 5, null, { timeout: 30000 });

  await page.screenshot({ path: join(outDir, 'color.png') });
  const colour = await page.evaluate(() => window.viewerPixelStats());
  check(colour.drawn > 0.1, `mesh drawn in colour mode: ${(100 * colour.drawn).toFixed(1)} % of pixels`);

  await page.click('label:has(input[value=classes])');
  await page.waitForFunction(() => window.viewerState.mode === 'classes');
  await page.waitForTimeout(300);
  await page.screenshot({ path: join(outDir, 'classes.png') });
  const classes = await page.evaluate(() => window.viewerPixelStats());
  const present = Object.entries(classes.classes).filter(([, share]) => share > 0.003).map(([name]) => name);
  check(classes.drawn > 0.1, `mesh drawn in classes mode: ${(100 * classes.drawn).toFixed(1)} % of pixels`);
  if (loaded.labelled) {
    check(present.length >= 2, `class colours present: ${present.join(', ') || 'none'}`);
  }

  await page.click('label:has(input[value=geometry])');
  await page.waitForFunction(() => window.viewerState.mode === 'geometry');
  await page.waitForTimeout(200);
  await page.screenshot({ path: join(outDir, 'geometry.png') });
  const geometry = await page.evaluate(() => window.viewerPixelStats());
  check(geometry.drawn > 0.1 && Object.values(geometry.classes).reduce((a, b) => a + b, 0) < 0.01,
    `plain geometry drawn without class colours (${(100 * geometry.drawn).toFixed(1)} % of pixels)`);
  await page.click('label:has(input[value=classes])');

  // Click in the middle of the view, where the camera looks at the room.
  const canvas = await page.$('#view canvas');
  const box = await canvas.boundingBox();
  // Reconstructions have holes: try a few points around the middle until one hits the mesh.
  const spots = [[0.55, 0.55], [0.5, 0.6], [0.6, 0.5], [0.45, 0.5], [0.5, 0.45], [0.65, 0.65], [0.4, 0.6], [0.55, 0.4]];
  for (const [fx, fy] of spots) {
    await page.mouse.click(box.x + box.width * fx, box.y + box.height * fy);
    const thrown = await page.waitForFunction(() => window.viewerState.throws >= 1, null, { timeout: isStatic ? 2000 : 10000 })
      .then(() => true, () => false);
    if (thrown) break;
  }
  const first = await page.evaluate(() => ({ ...window.viewerState.ball, throws: window.viewerState.throws, last: window.viewerState.lastThrow }));
  check(first.throws >= 1, `a click threw a ball (${isStatic ? 'replayed' : 'simulated by the server'}): ${JSON.stringify(first.last)}`);
  await page.waitForTimeout(250);
  await page.screenshot({ path: join(outDir, 'throw.png') });
  const second = await page.evaluate(() => ({ ...window.viewerState.ball }));
  const moved = first.position && second.position &&
    Math.hypot(...first.position.map((x, i) => x - second.position[i])) > 0.01;
  check(!!moved, `the ball moves: ${JSON.stringify(first.position)} -> ${JSON.stringify(second.position)}`);

  check(consoleErrors.length === 0, `no errors in the console${consoleErrors.length ? ': ' + consoleErrors.join(' | ') : ''}`);
} finally {
  await browser.close();
}
if (failures.length) {
  console.error(`${failures.length} browser check(s) failed`);
  process.exit(1);
}
console.log('all browser checks passed');
