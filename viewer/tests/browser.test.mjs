// Browser tests of the viewer in real Chromium (Debian's /usr/bin/chromium, headless, software
// WebGL) driven by playwright-core: the demo's report.html from disk and a `fascicle view` session.
// Environment: FASCICLE_CLI (the fascicle binary, required), FASCICLE_CHROMIUM (default
// /usr/bin/chromium), FASCICLE_TEST_ARTIFACTS (screenshots; default viewer/test-artifacts).
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import { spawn, spawnSync } from 'node:child_process';
import fs from 'node:fs';
import http from 'node:http';
import os from 'node:os';
import path from 'node:path';
import { fileURLToPath, pathToFileURL } from 'node:url';

const here = path.dirname(fileURLToPath(import.meta.url));
const cli = process.env.FASCICLE_CLI;
const chromiumPath = process.env.FASCICLE_CHROMIUM || '/usr/bin/chromium';
const artifacts = process.env.FASCICLE_TEST_ARTIFACTS || path.join(here, '..', 'test-artifacts');
// Exactly the flags of issue 9, plus the pipe playwright talks over and a fresh profile.
const FLAGS = ['--headless', '--no-sandbox', '--disable-gpu', '--no-first-run', '--disable-background-networking',
  '--disable-component-update', '--disable-sync'];

function requireSetup() {
  const missing = [];
  if (!cli || !fs.existsSync(cli)) missing.push(`the fascicle binary (FASCICLE_CLI='${cli ?? ''}'; build it with \`make build\`)`);
  if (!fs.existsSync(chromiumPath)) missing.push(`chromium at ${chromiumPath} (install it with \`make deps\`, Debian package chromium)`);
  if (!fs.existsSync(path.join(here, '..', 'node_modules', 'playwright-core')))
    missing.push('viewer/node_modules (run `make build`, which runs npm ci in viewer/)');
  const assets = process.env.FASCICLE_VIEWER_DIR || path.join(here, '..', 'dist');
  if (!fs.existsSync(path.join(assets, 'viewer.js')))
    missing.push(`the built viewer ${path.join(assets, 'viewer.js')} (run \`make build\`, which runs the Vite build)`);
  if (missing.length) throw new Error(`viewer browser tests cannot run; missing: ${missing.join('; ')}`);
}

let chromium, context, tmp, demoDir;

before(async () => {
  requireSetup();
  ({ chromium } = await import('playwright-core'));
  fs.mkdirSync(artifacts, { recursive: true });
  tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'fascicle-viewer-test-'));
  demoDir = path.join(tmp, 'demo');
  // The Hill curves and an isometric experiment beside the run: the report gets an experiments page.
  for (const args of [['muscle', 'curves'], ['muscle', 'experiment', 'isometric']]) {
    const e = spawnSync(cli, ['--quiet', ...args, '--out', path.join(demoDir, 'experiments')], { encoding: 'utf8' });
    assert.equal(e.status, 0, `fascicle ${args.join(' ')} failed: ${e.stderr}`);
  }
  const r = spawnSync(cli, ['--quiet', '--threads', '2', 'demo', '--out', demoDir, '--fps', '10'], { encoding: 'utf8' });
  assert.equal(r.status, 0, `fascicle demo failed: ${r.stderr}`);
  const profile = path.join(tmp, 'chromium-profile');
  fs.mkdirSync(profile);
  context = await chromium.launchPersistentContext(profile, {
    executablePath: chromiumPath, headless: true, ignoreDefaultArgs: true,
    args: [...FLAGS, `--user-data-dir=${profile}`, '--remote-debugging-pipe', 'about:blank'],
    viewport: { width: 1280, height: 800 },
  });
});

after(async () => {
  if (context) await context.close();
  if (tmp) fs.rmSync(tmp, { recursive: true, force: true });
});

// Runs a test body; on failure saves a screenshot of every open page next to the other artifacts.
function withScreenshots(name, body) {
  return async () => {
    try {
      await body();
    } catch (e) {
      let k = 0;
      for (const p of context ? context.pages() : [])
        await p.screenshot({ path: path.join(artifacts, `failed-${name}-${k++}.png`) }).catch(() => {});
      throw e;
    }
  };
}

async function openViewer(url) {
  const page = await context.newPage();
  const errors = [];
  page.on('pageerror', (e) => errors.push(String(e)));
  await page.goto(url);
  await page.waitForFunction(() => window.fascicle && window.fascicle.status !== 'loading', null, { timeout: 60000 });
  const status = await page.evaluate(() => [window.fascicle.status, window.fascicle.message]);
  assert.equal(status[0], 'ready', `viewer did not start: ${status[1]} ${errors.join('; ')}`);
  return page;
}

// Grey levels of the 3D view (downsampled), with their mean and variance.
async function scenePixels(page) {
  return page.evaluate(() => {
    window.fascicle.renderNow();
    const src = document.querySelector('#view canvas');
    const c = document.createElement('canvas');
    c.width = 160; c.height = 100;
    const ctx = c.getContext('2d');
    ctx.drawImage(src, 0, 0, c.width, c.height);
    const d = ctx.getImageData(0, 0, c.width, c.height).data;
    const grey = [];
    for (let i = 0; i < d.length; i += 4) grey.push(0.299 * d[i] + 0.587 * d[i + 1] + 0.114 * d[i + 2]);
    const mean = grey.reduce((a, b) => a + b, 0) / grey.length;
    const variance = grey.reduce((a, b) => a + (b - mean) ** 2, 0) / grey.length;
    return { grey, mean, variance };
  });
}

const meanAbsDiff = (a, b) => a.grey.reduce((s, v, i) => s + Math.abs(v - b.grey[i]), 0) / a.grey.length;

async function checkScene(page, label) {
  const px = await scenePixels(page);
  assert.ok(px.variance > 50, `${label}: the canvas looks blank (grey variance ${px.variance.toFixed(1)})`);
  const objects = await page.evaluate(() => window.fascicle.listObjects());
  const kinds = (k) => objects.filter((o) => o.name.startsWith(k + ':') && o.vertices > 0);
  assert.ok(kinds('bone').length >= 4, `${label}: bones in the scene graph: ${kinds('bone').length}`);
  assert.ok(kinds('muscle').length >= 3, `${label}: muscle surfaces in the scene graph: ${kinds('muscle').length}`);
  assert.ok(kinds('fibres').length >= 3, `${label}: fibre sets in the scene graph: ${kinds('fibres').length}`);
  assert.ok(kinds('action_line').length >= 3, `${label}: action lines: ${kinds('action_line').length}`);
  return { px, objects };
}

async function plotImage(page) {
  return page.evaluate(() => document.querySelector('#plots .plot canvas').toDataURL());
}

test('report.html opens from disk: scene, scrubbing, plots, muscle toggle', withScreenshots('report', async () => {
  const page = await openViewer(pathToFileURL(path.join(demoDir, 'report.html')).href);
  const { px: first, objects } = await checkScene(page, 'report');
  await page.screenshot({ path: path.join(artifacts, 'report.png') });

  // Scrub with the timeline slider to the middle frame (the demo's motion ends where it starts):
  // the plot's time marker and the picture move.
  const plotBefore = await plotImage(page);
  const count = await page.evaluate(() => window.fascicle.frameCount);
  assert.equal(count, 21, 'frames embedded');
  await page.locator('#scrub').fill('10');
  assert.equal(await page.evaluate(() => window.fascicle.getFrame()), 10);
  const afterScrub = await scenePixels(page);
  assert.ok(meanAbsDiff(first, afterScrub) > 0.5, `the picture did not change on scrubbing (${meanAbsDiff(first, afterScrub)})`);
  assert.notEqual(await plotImage(page), plotBefore, 'the plot did not change on scrubbing');
  assert.match(await page.locator('#timeline .time').innerText(), /t = 1\.000 s/);
  await page.screenshot({ path: path.join(artifacts, 'report-mid-frame.png') });

  // Colour the fibres by force: the legend says so (N) and the fibres' colours change.
  const strainColours = await scenePixels(page);
  await page.locator('#colour-mode').selectOption('force');
  assert.match(await page.locator('#legend').innerText(), /fibre force \(N\)/);
  assert.ok(meanAbsDiff(strainColours, await scenePixels(page)) > 0.01, 'fibre colours unchanged by the force scale');
  await page.locator('#colour-mode').selectOption('strain');

  // Select another muscle: its name and plots appear.
  const muscle = objects.find((o) => o.name.startsWith('muscle:')).name.slice('muscle:'.length);
  await page.locator(`#muscle-list .row[data-muscle="${muscle}"] span:last-child`).click();
  assert.equal(await page.locator('#plot-title').innerText(), muscle);
  assert.ok(await page.locator('#plots .plot canvas').count() >= 4, 'plots of the selected muscle');

  // Toggle it off in the list: hidden in the scene graph and gone from the picture.
  const before = await scenePixels(page);
  await page.locator(`input[data-muscle-toggle="${muscle}"]`).uncheck();
  const hidden = (await page.evaluate(() => window.fascicle.listObjects())).filter((o) => o.name.endsWith(':' + muscle));
  assert.ok(hidden.length >= 2 && hidden.every((o) => !o.visible), `objects of ${muscle} still visible`);
  const without = await scenePixels(page);
  assert.ok(meanAbsDiff(before, without) > 0.2, `the picture did not change when ${muscle} was hidden`);

  // Search filters the list.
  await page.locator('#muscle-search').fill(muscle.slice(0, 5));
  const shown = await page.locator('#muscle-list .row[data-muscle]:not(.hidden)').count();
  assert.ok(shown >= 1 && shown < objects.filter((o) => o.name.startsWith('muscle:')).length, `search shows ${shown}`);

  // Play at 4× from the first frame: frames advance; pause stops them.
  await page.evaluate(() => window.fascicle.setFrame(0));
  await page.locator('#speed').selectOption('4');
  await page.locator('#play').click();
  await page.waitForFunction(() => window.fascicle.getFrame() >= 3, null, { timeout: 10000 });
  await page.locator('#play').click();
  assert.equal(await page.locator('#play').innerText(), 'Play');
  const paused = await page.evaluate(() => window.fascicle.getFrame());
  await page.waitForTimeout(300);
  assert.equal(await page.evaluate(() => window.fascicle.getFrame()), paused, 'frames advance while paused');

  // Muscle experiments page: one plot per table found beside the run.
  await page.locator('header nav button[data-page="experiments"]').click();
  for (const name of ['isometric', 'force_length', 'force_velocity', 'tendon_force_length'])
    assert.equal(await page.locator(`#page .plot[data-experiment="${name}"] canvas`).count(), 1, `experiment plot ${name}`);
  await page.screenshot({ path: path.join(artifacts, 'report-experiments.png') });

  // Summary page.
  await page.locator('header nav button[data-page="summary"]').click();
  assert.match(await page.locator('#run-summary').innerText(), /21 of 21/);
  await page.close();
}));

function startView(dir, extra = []) {
  const proc = spawn(cli, ['view', dir, '--port', '0', '--max-seconds', '120', ...extra], { stdio: ['ignore', 'pipe', 'pipe'] });
  return new Promise((resolve, reject) => {
    let out = '', err = '';
    proc.stdout.on('data', (d) => {
      out += d;
      const m = out.match(/http:\/\/127\.0\.0\.1:(\d+)\//);
      if (m) resolve({ proc, url: m[0], port: Number(m[1]) });
    });
    proc.stderr.on('data', (d) => (err += d));
    proc.on('exit', (code) => reject(new Error(`fascicle view exited (${code}): ${err}`)));
  });
}

// A GET with the path sent exactly as written (no client-side normalisation of '..').
function rawGet(port, rawPath) {
  return new Promise((resolve, reject) => {
    const req = http.request({ host: '127.0.0.1', port, path: rawPath, method: 'GET' }, (res) => {
      let body = '';
      res.on('data', (d) => (body += d));
      res.on('end', () => resolve({ status: res.statusCode, body }));
    });
    req.on('error', reject);
    req.end();
  });
}

test('fascicle view serves the run and the viewer; traversal is refused', withScreenshots('view', async () => {
  const { proc, url, port } = await startView(demoDir);
  try {
    const page = await openViewer(url);
    const { px } = await checkScene(page, 'view');
    await page.screenshot({ path: path.join(artifacts, 'view.png') });
    assert.equal(await page.evaluate(() => window.fascicle.frameCount), 21);
    await page.evaluate(() => window.fascicle.setFrame(10));
    assert.ok(meanAbsDiff(px, await scenePixels(page)) > 0.5, 'picture unchanged after setFrame');
    await page.close();

    const secret = path.join(tmp, 'secret.txt');
    fs.writeFileSync(secret, 'do not serve');
    for (const p of ['/run/../secret.txt', '/run/viewer/../../secret.txt', '/../secret.txt', '/run/%2e%2e/secret.txt',
      '/run/..%2fsecret.txt', '/run//etc/passwd', '/run/../../../../etc/passwd']) {
      const r = await rawGet(port, p);
      assert.ok(r.status === 403 || r.status === 404, `${p} → ${r.status}`);
      assert.ok(!r.body.includes('do not serve') && !r.body.includes('root:'), `${p} leaked a file`);
    }
    assert.equal((await rawGet(port, '/run/viewer/manifest.json')).status, 200);
    assert.equal((await rawGet(port, '/run/demo.pvd')).status, 200);

    // The same port again: a clear error, exit code 3.
    const second = spawnSync(cli, ['view', demoDir, '--port', String(port), '--max-seconds', '1'], { encoding: 'utf8' });
    assert.equal(second.status, 3, second.stderr);
    assert.match(second.stderr, /port \d+ on 127\.0\.0\.1 is in use/);
  } finally {
    proc.kill('SIGINT');
  }
}));

test('a folder that is not a run, and a run with a missing frame, are explained on the page', withScreenshots('bad-input', async () => {
  const empty = path.join(tmp, 'not-a-run');
  fs.mkdirSync(empty);
  let server = await startView(empty);
  try {
    const page = await context.newPage();
    await page.goto(server.url);
    await page.waitForFunction(() => window.fascicle && window.fascicle.status === 'error', null, { timeout: 30000 });
    const text = await page.locator('#fatal').innerText();
    assert.match(text, /not a fascicle run/);
    assert.match(text, /manifest\.json is missing/);
    await page.close();
  } finally {
    server.proc.kill('SIGINT');
  }

  const damaged = path.join(tmp, 'damaged');
  fs.cpSync(demoDir, damaged, { recursive: true });
  fs.rmSync(path.join(damaged, 'viewer', 'frames', '00007.bin'));
  // ... and as if the run had stopped early.
  const manifestPath = path.join(damaged, 'viewer', 'manifest.json');
  const manifest = JSON.parse(fs.readFileSync(manifestPath, 'utf8'));
  Object.assign(manifest, { complete: false, frames_expected: 30 });
  fs.writeFileSync(manifestPath, JSON.stringify(manifest));
  server = await startView(damaged);
  try {
    const page = await openViewer(server.url);
    assert.match(await page.locator('#notices').innerText(), /1 frame file\(s\) are missing.*00007\.bin/);
    assert.match(await page.locator('#notices').innerText(), /Run incomplete: 21 of 30 frames were written/);
    assert.equal(await page.evaluate(() => window.fascicle.frameCount), 20);
    await page.close();
  } finally {
    server.proc.kill('SIGINT');
  }
}));

test('the .glb of `fascicle export --gltf` loads in three.js (GLTFLoader)', async () => {
  const glb = path.join(tmp, 'scene.glb');
  const r = spawnSync(cli, ['--quiet', 'export', '--gltf', demoDir, '--frame', '10', '--out', glb], { encoding: 'utf8' });
  assert.equal(r.status, 0, r.stderr);
  const { GLTFLoader } = await import('three/examples/jsm/loaders/GLTFLoader.js');
  const buf = fs.readFileSync(glb);
  const gltf = await new Promise((resolve, reject) =>
    new GLTFLoader().parse(buf.buffer.slice(buf.byteOffset, buf.byteOffset + buf.byteLength), '', resolve, reject));
  const byPrefix = (prefix, kind) => {
    const found = [];
    gltf.scene.traverse((o) => { if (o[kind] && o.name.startsWith(prefix)) found.push(o); });
    return found;
  };
  assert.equal(byPrefix('bone_', 'isMesh').length, 6);
  const muscles = byPrefix('muscle_', 'isMesh');
  assert.equal(muscles.length, 4);
  assert.ok(muscles.every((m) => m.material.transparent && m.material.opacity < 1), 'muscles are translucent');
  assert.equal(byPrefix('fibres_', 'isLineSegments').length, 4);
  assert.equal(byPrefix('action_line_', 'isLineSegments').length, 4);
});
