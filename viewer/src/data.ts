// Loading a run: the manifest, the static mesh and the frames, either embedded in report.html
// (base64, positions quantised to 16 bits in the manifest's box) or fetched from `fascicle view`
// (run/viewer/*, float32). Binary layouts: docs/viewer.md and src/report/viewer_data.cpp.

export interface MuscleInfo {
  name: string;
  color: [number, number, number];
  representation: string;
  actuator: string;
  fibre_template: string;
  rest_volume_m3: number;
  has_surface: boolean;
  metrics: Record<string, (number | null)[]>;
}

export interface ExperimentTable {
  name: string;
  file: string;
  columns: string[];
  data: number[][];
}

export interface Manifest {
  format: string;
  version: number;
  scene: string;
  frames_expected: number;
  frames_written: number;
  complete: boolean;
  frame_rate_hz: number;
  times_s: number[];
  mesh_file: string;
  frame_files: string[];
  bodies: { name: string; mass_kg: number; mesh_volume_m3: number; X_ground_default?: number[] }[];
  metric_names: string[];
  muscles: MuscleInfo[];
  box_m: [number[], number[]];
  summary?: Record<string, unknown>;
  experiments: ExperimentTable[];
  embedded?: { position_encoding: string; frame_indices: number[]; subsampled: boolean; step: number };
}

export interface StaticMesh {
  bodies: { vertices: Float32Array; triangles: Uint32Array }[];
  muscleTriangles: Uint32Array[];
}

export interface MuscleFrame {
  surface: Float32Array;       // #V*3
  actionLine: Float32Array;    // #points*3
  fibres: Float32Array[];      // per fibre, #points*3
  fibreStrain: Float32Array;   // per fibre (may be empty)
}

export interface Frame {
  time: number;
  bodyMatrices: Float32Array[];  // 16 each, column-major
  muscles: MuscleFrame[];
}

export interface Run {
  manifest: Manifest;
  mesh: StaticMesh;
  frames: Frame[];          // the frames available (embedded subset or all)
  frameNumbers: number[];   // their index among the frames written
  embedded: boolean;
  missingFrames: number[];  // frames listed but not loadable
}

class Reader {
  private at = 0;
  private view: DataView;
  constructor(private buf: ArrayBuffer, private what: string) {
    this.view = new DataView(buf);
  }
  need(n: number) {
    if (this.at + n > this.buf.byteLength) throw new Error(`${this.what} is truncated`);
  }
  u32() { this.need(4); const v = this.view.getUint32(this.at, true); this.at += 4; return v; }
  u16() { this.need(2); const v = this.view.getUint16(this.at, true); this.at += 2; return v; }
  f32() { this.need(4); const v = this.view.getFloat32(this.at, true); this.at += 4; return v; }
  f64() { this.need(8); const v = this.view.getFloat64(this.at, true); this.at += 8; return v; }
  tag(expected: string) {
    this.need(4);
    const t = String.fromCharCode(...new Uint8Array(this.buf, 0, 4));
    if (t !== expected) throw new Error(`${this.what} is not a fascicle viewer file (tag '${t}')`);
    this.at = 4;
  }
  f32array(n: number) { const a = new Float32Array(n); for (let i = 0; i < n; i++) a[i] = this.f32(); return a; }
  u32array(n: number) { const a = new Uint32Array(n); for (let i = 0; i < n; i++) a[i] = this.u32(); return a; }
}

export function decodeMesh(buf: ArrayBuffer): StaticMesh {
  const r = new Reader(buf, 'mesh.bin');
  r.tag('FVM1');
  const nb = r.u32();
  const bodies = [];
  for (let b = 0; b < nb; b++) {
    const nv = r.u32(), nf = r.u32();
    bodies.push({ vertices: r.f32array(nv * 3), triangles: r.u32array(nf * 3) });
  }
  const nm = r.u32();
  const muscleTriangles = [];
  for (let m = 0; m < nm; m++) muscleTriangles.push(r.u32array(r.u32() * 3));
  return { bodies, muscleTriangles };
}

export function decodeFrame(buf: ArrayBuffer, box: [number[], number[]], what: string): Frame {
  const r = new Reader(buf, what);
  r.tag('FVF1');
  const encoding = r.u32();
  if (encoding !== 0 && encoding !== 1) throw new Error(`${what}: unknown position encoding ${encoding}`);
  const time = r.f64();
  const nb = r.u32(), nm = r.u32();
  const bodyMatrices = [];
  for (let b = 0; b < nb; b++) bodyMatrices.push(r.f32array(16));
  const counts = [];
  for (let m = 0; m < nm; m++) {
    const surface = r.u32(), action = r.u32(), nf = r.u32(), strain = r.u32();
    const fibres = [];
    for (let k = 0; k < nf; k++) fibres.push(r.u32());
    counts.push({ surface, action, strain, fibres });
  }
  const lo = box[0], scale = [0, 1, 2].map((k) => (box[1][k] - box[0][k]) / 65535);
  const points = (n: number) => {
    const a = new Float32Array(n * 3);
    if (encoding === 0) for (let i = 0; i < n * 3; i++) a[i] = r.f32();
    else for (let i = 0; i < n * 3; i++) a[i] = lo[i % 3] + r.u16() * scale[i % 3];
    return a;
  };
  const muscles: MuscleFrame[] = counts.map((c) => ({
    surface: points(c.surface),
    actionLine: points(c.action),
    fibres: c.fibres.map((n) => points(n)),
    fibreStrain: new Float32Array(0),
  }));
  counts.forEach((c, m) => (muscles[m].fibreStrain = r.f32array(c.strain)));
  return { time, bodyMatrices, muscles };
}

function base64ToBuffer(text: string): ArrayBuffer {
  const bin = atob(text.trim());
  const out = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) out[i] = bin.charCodeAt(i);
  return out.buffer;
}

export function findEmbedded(): boolean {
  return document.getElementById('fascicle-manifest') !== null;
}

export function loadEmbedded(): Run {
  const manifest = JSON.parse(document.getElementById('fascicle-manifest')!.textContent || '{}') as Manifest;
  checkManifest(manifest);
  const mesh = decodeMesh(base64ToBuffer(document.getElementById('fascicle-mesh')!.textContent || ''));
  const elements = Array.from(document.querySelectorAll('script.fascicle-frame'));
  const frames = elements.map((e, i) => decodeFrame(base64ToBuffer(e.textContent || ''), manifest.box_m, `embedded frame ${i}`));
  const frameNumbers = manifest.embedded ? manifest.embedded.frame_indices.slice(0, frames.length) : frames.map((_, i) => i);
  return { manifest, mesh, frames, frameNumbers, embedded: true, missingFrames: [] };
}

export class MissingRunError extends Error {}

function checkManifest(m: Manifest) {
  if (m.format !== 'fascicle-viewer') throw new MissingRunError('viewer/manifest.json is not a fascicle viewer manifest');
  if (m.version !== 1) throw new MissingRunError(`viewer/manifest.json has version ${m.version}; this viewer reads version 1`);
}

async function fetchOk(url: string, what: string): Promise<Response> {
  const res = await fetch(url, { cache: 'no-store' });
  if (!res.ok) throw new MissingRunError(`${what} is missing (${url}: HTTP ${res.status})`);
  return res;
}

export async function loadServed(base: string, progress: (done: number, total: number) => void): Promise<Run> {
  const manifest = (await (await fetchOk(`${base}manifest.json`, 'viewer/manifest.json')).json()) as Manifest;
  checkManifest(manifest);
  const mesh = decodeMesh(await (await fetchOk(base + manifest.mesh_file, 'viewer/mesh.bin')).arrayBuffer());
  const frames: Frame[] = [];
  const frameNumbers: number[] = [];
  const missingFrames: number[] = [];
  const total = manifest.frame_files.length;
  for (let i = 0; i < total; i++) {
    try {
      const res = await fetch(base + manifest.frame_files[i], { cache: 'no-store' });
      if (!res.ok) throw new Error(`HTTP ${res.status}`);
      frames.push(decodeFrame(await res.arrayBuffer(), manifest.box_m, manifest.frame_files[i]));
      frameNumbers.push(i);
    } catch {
      missingFrames.push(i);
    }
    progress(i + 1, total);
  }
  return { manifest, mesh, frames, frameNumbers, embedded: false, missingFrames };
}
