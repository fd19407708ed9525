// Screenshot the viewer in headless Debian Chromium (Playwright):
//   node screenshot.mjs URL OUT.png WIDTH HEIGHT
// Prints a JSON line {ok, bound, error, console} and exits non-zero when the page failed.
import { mkdtempSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { chromium } from 'playwright-core';

const [url, out, w, h] = process.argv.slice(2);
const width = Number(w) || 480;
const height = Number(h) || 480;
const profile = mkdtempSync(join(tmpdir(), 'pdic-chromium-'));
const flags = ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
  '--disable-background-networking', '--disable-component-update', '--disable-sync',
  '--use-angle=swiftshader', '--enable-unsafe-swiftshader'];
const messages = [];
let context;
try {
  context = await chromium.launchPersistentContext(profile, {
    executablePath: process.env.PDIC_CHROMIUM || '/usr/bin/chromium',
    headless: true, args: flags, viewport: { width, height }, deviceScaleFactor: 1,
  });
  const page = context.pages()[0] || await context.newPage();
  page.on('console', (m) => messages.push(`${m.type()}: ${m.text()}`));
  page.on('pageerror', (e) => messages.push(`pageerror: ${e.message}`));
  await page.goto(url, { waitUntil: 'load', timeout: 60000 });
  await page.waitForFunction(() => window.pdicViewer !== undefined, null, { timeout: 120000 });
  const state = await page.evaluate(() => window.pdicViewer);
  await page.evaluate(() => new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(r))));
  await page.locator('canvas').screenshot({ path: out });
  console.log(JSON.stringify({ ok: !!state.ready, bound: state.bound, background: state.background, error: state.error || null, console: messages }));
  process.exitCode = state.ready ? 0 : 1;
} catch (error) {
  console.log(JSON.stringify({ ok: false, error: String(error), console: messages }));
  process.exitCode = 1;
} finally {
  if (context) await context.close();
  rmSync(profile, { recursive: true, force: true });
}
