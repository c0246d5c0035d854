// fascicle viewer: report.html (data embedded) and `fascicle view` (data fetched from run/viewer/).
import uPlot from 'uplot';
import 'uplot/dist/uPlot.min.css';
import './style.css';
import { findEmbedded, loadEmbedded, loadServed, MissingRunError, type Run } from './data';
import { drawLegend, type ColourMode } from './colormap';
import { SceneView, type FibreScale } from './scene';

// Plots of the selected muscle: metric name → title and scale to display units.
const PLOTS: { metric: string; fallback?: string; title: string; scale: number; unit: string }[] = [
  { metric: 'relative_volume_change', title: 'Volume error', scale: 100, unit: '%' },
  { metric: 'musculotendon_length_m', title: 'Musculotendon length', scale: 100, unit: 'cm' },
  { metric: 'mean_fibre_length_m', fallback: 'fiber_length_m', title: 'Mean fibre length', scale: 100, unit: 'cm' },
  { metric: 'mean_pennation_rad', fallback: 'pennation_rad', title: 'Pennation', scale: 180 / Math.PI, unit: '°' },
  { metric: 'tendon_force_N', title: 'Tendon force', scale: 1, unit: 'N' },
];

interface TestHooks {
  status: 'loading' | 'ready' | 'error';
  message: string;
  [k: string]: unknown;
}
declare global { interface Window { fascicle: TestHooks; } }

const hooks: TestHooks = { status: 'loading', message: '' };
window.fascicle = hooks;

function el<K extends keyof HTMLElementTagNameMap>(tag: K, attrs: Record<string, string> = {}, text = ''): HTMLElementTagNameMap[K] {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text) e.textContent = text;
  return e;
}

function fmt(v: number | null | undefined, digits = 4): string {
  return v === null || v === undefined || !Number.isFinite(v) ? '—' : Number(v).toPrecision(digits);
}

// Axis numbers: short, exponent form for tiny values.
function tick(v: number): string {
  if (v === 0 || !Number.isFinite(v)) return String(v);
  return Math.abs(v) < 1e-3 || Math.abs(v) >= 1e5 ? v.toExponential(1) : String(+v.toPrecision(3));
}

function showFatal(root: HTMLElement, title: string, detail: string) {
  root.innerHTML = '';
  root.style.display = 'block';
  const box = el('div', { id: 'fatal' });
  box.append(el('h1', {}, title), el('p', {}, detail));
  root.append(box);
  hooks.status = 'error';
  hooks.message = `${title}: ${detail}`;
}

class App {
  private view: SceneView;
  private frame = 0;
  private playing = false;
  private speed = 1;
  private selected = 0;
  private plots: uPlot[] = [];
  private slider: HTMLInputElement;
  private timeLabel: HTMLElement;
  private legendEnds: HTMLElement;
  private legendTitle: HTMLElement;
  private scales: Record<ColourMode, FibreScale>;
  private lastTick = 0;
  private playhead = 0;

  constructor(private root: HTMLElement, private run: Run) {
    const m = run.manifest;
    root.innerHTML = '';
    const header = el('header');
    header.append(el('h1', {}, `fascicle — ${m.scene || 'run'}`));
    const nav = el('nav');
    const pages: [string, string][] = [['scene', 'Scene'], ['summary', 'Summary']];
    if (m.experiments && m.experiments.length) pages.push(['experiments', 'Muscle experiments']);
    for (const [id, label] of pages) {
      const b = el('button', { 'data-page': id }, label);
      b.onclick = () => this.showPage(id);
      nav.append(b);
    }
    header.append(nav, el('span', { class: 'muted' }, `${m.frames_written} frames · ${m.muscles.length} muscles · ${m.bodies.length} bones`));
    const notices = el('div', { id: 'notices' });
    this.addNotices(notices);

    const list = el('div', { id: 'muscle-list' });
    const viewBox = el('div', { id: 'view' });
    const plots = el('div', { id: 'plots' });
    const page = el('div', { id: 'page', class: 'hidden' });
    const timeline = el('div', { id: 'timeline' });
    root.append(header, notices, list, viewBox, plots, page, timeline);

    this.view = new SceneView(viewBox, run);
    this.scales = this.calcScales();

    // Legend
    const legend = el('div', { id: 'legend' });
    const modeSelect = el('select', { id: 'colour-mode' });
    modeSelect.append(el('option', { value: 'strain' }, 'Fibre strain'), el('option', { value: 'force' }, 'Fibre force'));
    modeSelect.onchange = () => this.setColourMode(modeSelect.value as ColourMode);
    this.legendTitle = el('div');
    const bar = el('canvas', { width: '160', height: '10' });
    this.legendEnds = el('div', { class: 'ends' });
    legend.append(modeSelect, this.legendTitle, bar, this.legendEnds);
    viewBox.append(legend);
    this.legendCanvas = bar;

    this.buildList(list);
    this.buildTimeline(timeline);
    this.slider = timeline.querySelector('input[type=range]') as HTMLInputElement;
    this.timeLabel = timeline.querySelector('.time') as HTMLElement;
    this.buildPlots(plots);
    this.setColourMode('strain');
    this.setFrame(0);
    this.view.frameModel();
    this.installHooks();
    requestAnimationFrame((t) => this.tick(t));
  }
  private legendCanvas: HTMLCanvasElement;

  private addNotices(box: HTMLElement) {
    const m = this.run.manifest;
    const add = (text: string, error = false) => box.append(el('div', { class: error ? 'notice error' : 'notice' }, text));
    if (!m.complete)
      add(`Run incomplete: ${m.frames_written} of ${m.frames_expected} frames were written (the run stopped early or is still running).`, true);
    if (this.run.missingFrames.length)
      add(`${this.run.missingFrames.length} frame file(s) are missing or damaged (first: ${m.frame_files[this.run.missingFrames[0]]}); they are skipped.`, true);
    if (this.run.embedded && m.embedded?.subsampled)
      add(`This report embeds every ${m.embedded.step}th frame (${this.run.frames.length} of ${m.frames_written}) with positions quantised to 16 bits to stay small; \`fascicle view\` shows every frame at full resolution.`);
    if (this.run.frames.length === 0) add('The run has no frame to show.', true);
  }

  private calcScales(): Record<ColourMode, FibreScale> {
    let s = 0;
    for (const f of this.run.frames) for (const mf of f.muscles) for (const v of mf.fibreStrain) if (Number.isFinite(v)) s = Math.max(s, Math.abs(v));
    let fmax = 0;
    for (let i = 0; i < this.run.manifest.muscles.length; i++)
      for (let k = 0; k < this.run.manifest.frames_written; k++) {
        const v = this.fibreForce(i, k);
        if (Number.isFinite(v)) fmax = Math.max(fmax, v);
      }
    return { strain: { lo: -(s || 0.01), hi: s || 0.01, unit: '' }, force: { lo: 0, hi: fmax || 1, unit: 'N' } };
  }

  // Force along the fibres of muscle i at frame k (active + passive, Hill model; N).
  private fibreForce(i: number, k: number): number {
    const mt = this.run.manifest.muscles[i].metrics;
    const a = mt['active_fiber_force_N']?.[k], p = mt['passive_fiber_force_N']?.[k];
    return (a ?? NaN) + (p ?? 0);
  }

  private setColourMode(mode: ColourMode) {
    this.view.colourMode = mode;
    drawLegend(this.legendCanvas, mode);
    const s = this.scales[mode];
    this.legendTitle.textContent = mode === 'strain' ? 'strain (length / rest − 1)' : 'fibre force (N)';
    this.legendEnds.innerHTML = '';
    this.legendEnds.append(el('span', {}, fmt(s.lo, 3)), el('span', {}, fmt(s.hi, 3)));
    this.setFrame(this.frame);
  }

  private buildList(list: HTMLElement) {
    const search = el('input', { type: 'search', placeholder: 'Search muscles', id: 'muscle-search' });
    list.append(el('h3', {}, 'Muscles'), search);
    const rows: HTMLElement[] = [];
    this.run.manifest.muscles.forEach((mu, i) => {
      const row = el('div', { class: 'row', 'data-muscle': mu.name });
      const box = el('input', { type: 'checkbox', 'data-muscle-toggle': mu.name });
      box.checked = true;
      box.onchange = () => this.view.setMuscleVisible(i, box.checked);
      box.onclick = (e) => e.stopPropagation();
      const sw = el('span', { class: 'swatch' });
      sw.style.background = `rgb(${mu.color.map((c) => Math.round(c * 255)).join(',')})`;
      row.append(box, sw, el('span', {}, mu.name));
      row.onclick = () => this.select(i);
      rows.push(row);
      list.append(row);
    });
    search.oninput = () => {
      const q = search.value.trim().toLowerCase();
      rows.forEach((r) => r.classList.toggle('hidden', q !== '' && !(r.dataset.muscle || '').toLowerCase().includes(q)));
    };
    list.append(el('h3', {}, 'Show'));
    for (const [kind, label] of [['bone', 'Bones'], ['muscle', 'Muscle surfaces'], ['fibres', 'Fibres'], ['action_line', 'Action lines']] as const) {
      const row = el('label', { class: 'row' });
      const box = el('input', { type: 'checkbox', 'data-part-toggle': kind });
      box.checked = true;
      box.onchange = () => this.view.setPartVisible(kind, box.checked);
      row.append(box, el('span', {}, label));
      list.append(row);
    }
  }

  private buildTimeline(t: HTMLElement) {
    const play = el('button', { id: 'play' }, 'Play');
    play.onclick = () => {
      this.playing = !this.playing;
      play.textContent = this.playing ? 'Pause' : 'Play';
      this.lastTick = 0;
      this.playhead = this.run.frames[this.frame]?.time ?? 0;
    };
    const slider = el('input', { type: 'range', id: 'scrub', min: '0', max: String(Math.max(0, this.run.frames.length - 1)), value: '0', step: '1' });
    slider.oninput = () => this.setFrame(Number(slider.value));
    const speed = el('select', { id: 'speed' });
    for (const s of [0.1, 0.25, 0.5, 1, 2, 4]) {
      const o = el('option', { value: String(s) }, `${s}×`);
      if (s === 1) o.selected = true;
      speed.append(o);
    }
    speed.onchange = () => (this.speed = Number(speed.value));
    t.append(play, slider, el('span', { class: 'time' }), el('label', {}, 'speed '), speed);
  }

  private buildPlots(box: HTMLElement) {
    box.innerHTML = '';
    this.plots.forEach((p) => p.destroy());
    this.plots = [];
    const mu = this.run.manifest.muscles[this.selected];
    if (!mu) return;
    box.append(el('h2', { id: 'plot-title' }, mu.name));
    const times = this.run.manifest.times_s;
    const width = Math.max(200, (box.clientWidth || 340) - 30);
    for (const p of PLOTS) {
      let series = mu.metrics[p.metric];
      if ((!series || series.every((v) => v === null)) && p.fallback) series = mu.metrics[p.fallback];
      const wrap = el('div', { class: 'plot', 'data-metric': p.metric });
      wrap.append(el('div', { class: 'title' }, `${p.title} (${p.unit})`));
      box.append(wrap);
      if (!series || series.every((v) => v === null)) {
        wrap.append(el('div', { class: 'muted' }, 'not computed for this muscle'));
        continue;
      }
      const ys = series.map((v) => (v === null ? null : v * p.scale));
      const marker = this;
      const plot = new uPlot({
        width, height: 120, legend: { show: false }, cursor: { show: true },
        scales: { x: { time: false } },
        axes: [{ size: 28 }, { size: 72, values: (_u: uPlot, vals: number[]) => vals.map(tick) }],
        series: [{}, { stroke: `rgb(${mu.color.map((c) => Math.round(c * 255)).join(',')})`, width: 1.5 }],
        hooks: {
          draw: [(u: uPlot) => {
            // The current time as a vertical line.
            const t = marker.run.frames[marker.frame]?.time;
            if (t === undefined) return;
            const x = u.valToPos(t, 'x', true);
            const ctx = u.ctx;
            ctx.save();
            ctx.strokeStyle = '#b8322a';
            ctx.lineWidth = 1.5;
            ctx.beginPath();
            ctx.moveTo(x, u.bbox.top);
            ctx.lineTo(x, u.bbox.top + u.bbox.height);
            ctx.stroke();
            ctx.restore();
          }],
        },
      }, [times, ys as (number | null)[]] as uPlot.AlignedData, wrap);
      this.plots.push(plot);
    }
    // Summary numbers of the selected muscle.
    const table = el('table');
    for (const name of this.run.manifest.metric_names) {
      const s = mu.metrics[name];
      const v = s?.filter((x): x is number => x !== null);
      if (!v || v.length === 0) continue;
      const tr = el('tr');
      tr.append(el('td', {}, name), el('td', {}, `${fmt(Math.min(...v))} … ${fmt(Math.max(...v))}`));
      table.append(tr);
    }
    box.append(el('div', { class: 'title' }, 'Range over the run'), table);
  }

  private select(i: number) {
    this.selected = i;
    document.querySelectorAll('#muscle-list .row[data-muscle]').forEach((r, k) => r.classList.toggle('selected', k === i));
    this.buildPlots(document.getElementById('plots')!);
  }

  setFrame(i: number) {
    const n = this.run.frames.length;
    if (n === 0) return;
    this.frame = Math.min(n - 1, Math.max(0, Math.round(i)));
    const f = this.run.frames[this.frame];
    const written = this.run.frameNumbers[this.frame];
    const scale = this.scales[this.view.colourMode];
    const value = this.view.colourMode === 'strain'
      ? (m: number, k: number) => f.muscles[m].fibreStrain[k] ?? NaN
      : (m: number) => this.fibreForce(m, written);
    this.view.showFrame(f, value, scale);
    if (this.slider) this.slider.value = String(this.frame);
    if (this.timeLabel) this.timeLabel.textContent = `t = ${f.time.toFixed(3)} s · frame ${written + 1}/${this.run.manifest.frames_written}`;
    this.plots.forEach((p) => p.redraw(false));
  }

  private tick(now: number) {
    if (this.playing && this.run.frames.length > 1) {
      if (this.lastTick) {
        const frames = this.run.frames;
        const t0 = frames[0].time, t1 = frames[frames.length - 1].time;
        this.playhead += ((now - this.lastTick) / 1000) * this.speed;
        if (this.playhead > t1) this.playhead = t0 + ((this.playhead - t0) % Math.max(t1 - t0, 1e-9));
        let k = this.frame;
        while (k + 1 < frames.length && frames[k + 1].time <= this.playhead) k++;
        if (frames[k].time > this.playhead) k = 0;
        while (k + 1 < frames.length && frames[k + 1].time <= this.playhead) k++;
        if (k !== this.frame) this.setFrame(k);
      }
      this.lastTick = now;
    }
    this.view.renderIfNeeded();
    requestAnimationFrame((t) => this.tick(t));
  }

  private showPage(id: string) {
    document.querySelectorAll('header nav button').forEach((b) => b.classList.toggle('active', (b as HTMLElement).dataset.page === id));
    const scene = id === 'scene';
    for (const sel of ['#muscle-list', '#view', '#plots', '#timeline']) document.querySelector(sel)!.classList.toggle('hidden', !scene);
    const page = document.getElementById('page')!;
    page.classList.toggle('hidden', scene);
    if (scene) { this.view.requestRender(); return; }
    page.innerHTML = '';
    if (id === 'summary') this.renderSummary(page);
    else this.renderExperiments(page);
  }

  private renderSummary(page: HTMLElement) {
    const m = this.run.manifest;
    const rows: [string, string][] = [
      ['scene', m.scene], ['frames written', `${m.frames_written} of ${m.frames_expected}`],
      ['complete', m.complete ? 'yes' : 'no'], ['frame rate', `${m.frame_rate_hz} Hz`],
      ['time', m.times_s.length ? `${m.times_s[0]} … ${m.times_s[m.times_s.length - 1]} s` : '—'],
    ];
    const t = el('table', { id: 'run-summary' });
    for (const [k, v] of rows) { const tr = el('tr'); tr.append(el('th', {}, k), el('td', {}, v)); t.append(tr); }
    page.append(el('h2', {}, 'Run'), t);
    const bt = el('table');
    bt.append(this.headerRow(['bone', 'mass (kg)', 'mesh volume (cm³)']));
    for (const b of m.bodies) { const tr = el('tr'); tr.append(el('td', {}, b.name), el('td', {}, fmt(b.mass_kg)), el('td', {}, fmt(b.mesh_volume_m3 * 1e6))); bt.append(tr); }
    page.append(el('h2', {}, 'Bones'), bt);
    const names = ['musculotendon_length_m', 'tendon_force_N', 'relative_volume_change', 'mean_fibre_length_m', 'max_bone_penetration_m'];
    const mt = el('table');
    mt.append(this.headerRow(['muscle', 'representation', 'rest volume (cm³)', ...names.map((n) => `${n} (min … max)`)]));
    for (const mu of m.muscles) {
      const tr = el('tr');
      tr.append(el('td', {}, mu.name), el('td', {}, mu.representation), el('td', {}, fmt(mu.rest_volume_m3 * 1e6)));
      for (const n of names) {
        const v = (mu.metrics[n] || []).filter((x): x is number => x !== null);
        tr.append(el('td', {}, v.length ? `${fmt(Math.min(...v), 3)} … ${fmt(Math.max(...v), 3)}` : '—'));
      }
      mt.append(tr);
    }
    page.append(el('h2', {}, 'Muscles'), mt);
  }

  private headerRow(cells: string[]) {
    const tr = el('tr');
    for (const c of cells) tr.append(el('th', {}, c));
    return tr;
  }

  private renderExperiments(page: HTMLElement) {
    page.append(el('h2', {}, 'Muscle experiments (Hill model)'));
    for (const ex of this.run.manifest.experiments) {
      const wrap = el('div', { class: 'plot', 'data-experiment': ex.name });
      wrap.append(el('h3', {}, `${ex.name} — ${ex.file}`));
      page.append(wrap);
      const x = ex.data[0];
      const series: uPlot.Series[] = [{ label: ex.columns[0] }];
      const palette = ['#b8322a', '#2a6db8', '#2a9d5c', '#9d5c2a', '#7a2ab8', '#555'];
      // Lengths and curve derivatives start hidden (other units); click the legend to show them.
      ex.columns.slice(1).forEach((c, k) => series.push({ label: c, stroke: palette[k % palette.length], width: 1.5,
        show: !(c.startsWith('d_') || c.endsWith('_m')) }));
      new uPlot({ width: Math.min(900, page.clientWidth - 40), height: 260, series, scales: { x: { time: false } },
        axes: [{ label: ex.columns[0] }, {}] },
        ex.data as uPlot.AlignedData, wrap);
      if (!x) wrap.append(el('div', {}, 'empty table'));
    }
  }

  // Hooks for the browser tests (viewer/tests) and for scripting in the console.
  private installHooks() {
    Object.assign(hooks, {
      frameCount: this.run.frames.length,
      getFrame: () => this.frame,
      setFrame: (i: number) => { this.setFrame(i); this.view.renderIfNeeded(); },
      listObjects: () => this.view.listObjects(),
      setMuscleVisible: (name: string, v: boolean) => {
        const box = document.querySelector(`input[data-muscle-toggle="${name}"]`) as HTMLInputElement | null;
        if (!box) return false;
        box.checked = v;
        box.dispatchEvent(new Event('change'));
        this.view.renderIfNeeded();
        return true;
      },
      selectMuscle: (name: string) => {
        const i = this.run.manifest.muscles.findIndex((m) => m.name === name);
        if (i >= 0) this.select(i);
        return i >= 0;
      },
      renderNow: () => { this.view.requestRender(); this.view.renderIfNeeded(); },
    });
    hooks.status = 'ready';
  }
}

async function boot() {
  let root = document.getElementById('app');
  if (!root) {
    root = el('div', { id: 'app' });
    document.body.append(root);
  }
  try {
    let run: Run;
    if (findEmbedded()) {
      run = loadEmbedded();
    } else {
      root.textContent = 'Loading run…';
      run = await loadServed('run/viewer/', (done, total) => (root!.textContent = `Loading frames ${done}/${total}…`));
    }
    new App(root, run);
  } catch (e) {
    const msg = e instanceof Error ? e.message : String(e);
    if (e instanceof MissingRunError)
      showFatal(root, 'This folder is not a fascicle run the viewer can show',
        `${msg}. Give \`fascicle view\` the output folder of \`fascicle run\` or \`fascicle demo\` (they write viewer/ and report.html with the default writers).`);
    else showFatal(root, 'The viewer could not show this run', msg);
  }
}

if (document.readyState === 'loading') document.addEventListener('DOMContentLoaded', () => void boot());
else void boot();
