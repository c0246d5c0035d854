// Colour scales for fibres and their legend. Strain: diverging blue–white–red, symmetric about 0.
// Force: sequential dark-blue → yellow (a viridis-like ramp).
export type ColourMode = 'strain' | 'force';

const diverging = [[0.23, 0.30, 0.75], [0.87, 0.87, 0.87], [0.71, 0.02, 0.15]];
const sequential = [[0.27, 0.00, 0.33], [0.23, 0.32, 0.55], [0.13, 0.57, 0.55], [0.37, 0.79, 0.38], [0.99, 0.91, 0.14]];

function ramp(stops: number[][], t: number): [number, number, number] {
  const x = Math.min(1, Math.max(0, Number.isFinite(t) ? t : 0)) * (stops.length - 1);
  const i = Math.min(stops.length - 2, Math.floor(x));
  const f = x - i;
  return [0, 1, 2].map((k) => stops[i][k] * (1 - f) + stops[i + 1][k] * f) as [number, number, number];
}

// value in [lo, hi] → rgb 0…1
export function colourFor(mode: ColourMode, value: number, lo: number, hi: number): [number, number, number] {
  const t = hi > lo ? (value - lo) / (hi - lo) : 0.5;
  return ramp(mode === 'strain' ? diverging : sequential, t);
}

export function drawLegend(canvas: HTMLCanvasElement, mode: ColourMode) {
  const ctx = canvas.getContext('2d');
  if (!ctx) return;
  for (let x = 0; x < canvas.width; x++) {
    const [r, g, b] = colourFor(mode, x / (canvas.width - 1), 0, 1);
    ctx.fillStyle = `rgb(${r * 255},${g * 255},${b * 255})`;
    ctx.fillRect(x, 0, 1, canvas.height);
  }
}
