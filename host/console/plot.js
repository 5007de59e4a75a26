// The top-down plot: NED metres, north up, east right, drawn in SVG.
//
// It shows the vehicle with its heading, the active setpoint, the mission's
// waypoints, the track flown and home. Drag or arrow keys pan, the wheel or
// +/- zoom, F fits everything in view again (and keeps it there until the
// next pan or zoom). A click, or Enter for the crosshair at the centre,
// fires a `pick` event with `detail: {n, e}`.
//
// Every marker carries its world position as `data-n`/`data-e` (metres)
// and its place on screen as `data-x`/`data-y` (pixels within the plot);
// the SVG element carries the view (`data-center-n`, `data-center-e`,
// `data-scale` in pixels per metre), so that what is drawn can be checked
// from the DOM.

const SVG_NS = 'http://www.w3.org/2000/svg';

/** Smallest span (metres) auto-fit zooms in to. */
const MIN_SPAN = 12;
/** Share of the plot auto-fit fills with content. */
const FILL = 0.7;
/** Pixels a press may move and still count as a click. */
const CLICK_SLOP = 5;
/** Metres the vehicle must move before the track gets a new point. */
const TRACK_STEP = 0.1;
/** Points of track kept. */
const TRACK_MAX = 5000;
/** Pixels per arrow-key press. */
const KEY_PAN = 60;

function el(name, attrs = {}, parent = null) {
  const node = document.createElementNS(SVG_NS, name);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, v);
  if (parent) parent.appendChild(node);
  return node;
}

/** A grid step of 1, 2 or 5 × 10^k metres at least `minPx` pixels wide. */
function gridStep(scale, minPx) {
  const raw = minPx / scale;
  const power = 10 ** Math.floor(Math.log10(raw));
  for (const m of [1, 2, 5, 10]) {
    if (m * power >= raw) return m * power;
  }
  return 10 * power;
}

function metres(value) {
  return `${Number(value.toFixed(2))} m`;
}

function position(node, p, screen) {
  node.dataset.n = p.n.toFixed(3);
  node.dataset.e = p.e.toFixed(3);
  node.dataset.x = screen.x.toFixed(1);
  node.dataset.y = screen.y.toFixed(1);
}

/** The plot in an `<svg>` element. */
export class Plot extends EventTarget {
  constructor(svg) {
    super();
    this.svg = svg;
    this.width = 600;
    this.height = 400;
    this.view = { n: 0, e: 0, scale: 20 };
    this.auto = true;
    this.vehicle = null;
    this.setpoint = null;
    this.home = null;
    this.waypoints = [];
    this.track = [];
    this.drawnWaypoints = null;
    this.#build();
    this.#listen();
    new ResizeObserver(() => this.#resize()).observe(svg);
    this.#resize();
  }

  #build() {
    const svg = this.svg;
    svg.replaceChildren();
    this.layers = {
      grid: el('g', { class: 'grid' }, svg),
      track: el('polyline', { class: 'track', points: '' }, svg),
      route: el('polyline', { class: 'route', points: '' }, svg),
      waypoints: el('g', { class: 'waypoints' }, svg),
      home: el('g', { class: 'home', id: 'home-marker', visibility: 'hidden' }, svg),
      leg: el('line', { class: 'leg', visibility: 'hidden' }, svg),
      setpoint: el('g', { class: 'setpoint', id: 'setpoint-marker', visibility: 'hidden' }, svg),
      vehicle: el('g', { class: 'vehicle', id: 'vehicle-marker', visibility: 'hidden' }, svg),
      crosshair: el('g', { class: 'crosshair' }, svg),
      overlay: el('g', { class: 'overlay' }, svg),
    };
    const { home, setpoint, vehicle, crosshair } = this.layers;
    el('rect', { x: -7, y: -7, width: 14, height: 14, rx: 2 }, home);
    el('text', { x: 0, y: 4, 'text-anchor': 'middle' }, home).textContent = 'H';
    el('circle', { r: 9 }, setpoint);
    el('path', { d: 'M-13,0H-5M5,0H13M0,-13V-5M0,5V13' }, setpoint);
    el('path', { class: 'body', d: 'M0,-14 L9,10 L0,5 L-9,10 Z' }, vehicle);
    el('path', { d: 'M-10,0H10M0,-10V10' }, crosshair);
    el('title', {}, home).textContent = 'home';
    el('title', {}, setpoint).textContent = 'active setpoint';
    el('title', {}, vehicle).textContent = 'vehicle';
  }

  #listen() {
    const svg = this.svg;
    let press = null;
    svg.addEventListener('pointerdown', (ev) => {
      if (ev.button !== 0) return;
      svg.setPointerCapture(ev.pointerId);
      press = { x: ev.clientX, y: ev.clientY, view: { ...this.view }, dragging: false };
    });
    svg.addEventListener('pointermove', (ev) => {
      if (!press) return;
      const dx = ev.clientX - press.x;
      const dy = ev.clientY - press.y;
      if (!press.dragging && Math.hypot(dx, dy) < CLICK_SLOP) return;
      press.dragging = true;
      this.auto = false;
      this.view.e = press.view.e - dx / this.view.scale;
      this.view.n = press.view.n + dy / this.view.scale;
      this.render();
    });
    svg.addEventListener('pointerup', (ev) => {
      if (press && !press.dragging) {
        const r = svg.getBoundingClientRect();
        this.#pick(this.toWorld(ev.clientX - r.left, ev.clientY - r.top));
      }
      press = null;
    });
    svg.addEventListener('pointercancel', () => { press = null; });
    svg.addEventListener('wheel', (ev) => {
      ev.preventDefault();
      const r = svg.getBoundingClientRect();
      this.zoom(Math.exp(-ev.deltaY * 0.0015), ev.clientX - r.left, ev.clientY - r.top);
    }, { passive: false });
    svg.addEventListener('keydown', (ev) => this.#key(ev));
  }

  #key(ev) {
    const pans = { ArrowUp: [0, -KEY_PAN], ArrowDown: [0, KEY_PAN], ArrowLeft: [-KEY_PAN, 0], ArrowRight: [KEY_PAN, 0] };
    if (pans[ev.key]) {
      const [dx, dy] = pans[ev.key];
      this.pan(dx, dy);
    } else if (ev.key === '+' || ev.key === '=') {
      this.zoom(1.25);
    } else if (ev.key === '-' || ev.key === '_') {
      this.zoom(0.8);
    } else if (ev.key === 'f' || ev.key === 'F') {
      this.fit();
    } else if (ev.key === 'Enter' || ev.key === ' ') {
      this.#pick({ n: this.view.n, e: this.view.e });
    } else {
      return;
    }
    ev.preventDefault();
  }

  #pick(point) {
    this.dispatchEvent(new CustomEvent('pick', { detail: point }));
  }

  #resize() {
    const r = this.svg.getBoundingClientRect();
    this.width = Math.max(1, Math.round(r.width));
    this.height = Math.max(1, Math.round(r.height));
    this.svg.setAttribute('viewBox', `0 0 ${this.width} ${this.height}`);
    this.render();
  }

  /** Screen pixels of a world point. */
  toScreen(p) {
    return {
      x: this.width / 2 + (p.e - this.view.e) * this.view.scale,
      y: this.height / 2 - (p.n - this.view.n) * this.view.scale,
    };
  }

  /** World point under screen pixels. */
  toWorld(x, y) {
    return {
      n: this.view.n - (y - this.height / 2) / this.view.scale,
      e: this.view.e + (x - this.width / 2) / this.view.scale,
    };
  }

  /** Pans by pixels (content moves the other way); ends auto-fit. */
  pan(dx, dy) {
    this.auto = false;
    this.view.e += dx / this.view.scale;
    this.view.n -= dy / this.view.scale;
    this.render();
  }

  /** Zooms by `factor` keeping the point under (x, y) in place; ends auto-fit. */
  zoom(factor, x = this.width / 2, y = this.height / 2) {
    const before = this.toWorld(x, y);
    this.auto = false;
    this.view.scale = Math.min(2000, Math.max(0.05, this.view.scale * factor));
    const after = this.toWorld(x, y);
    this.view.n += before.n - after.n;
    this.view.e += before.e - after.e;
    this.render();
  }

  /** Fits everything in view, and keeps doing so as things move. */
  fit() {
    this.auto = true;
    this.#fitNow();
    this.render();
  }

  /** The vehicle's position and heading (radians from north, clockwise). */
  setVehicle(p, yaw) {
    this.vehicle = p ? { n: p.n, e: p.e, yaw: yaw ?? 0 } : null;
    if (p) {
      const last = this.track.at(-1);
      if (!last || Math.hypot(last.n - p.n, last.e - p.e) >= TRACK_STEP) {
        this.track.push({ n: p.n, e: p.e });
        if (this.track.length > TRACK_MAX) this.track.splice(0, this.track.length - TRACK_MAX);
      }
    }
    this.#changed();
  }

  /** The active setpoint, or null. */
  setSetpoint(p) {
    this.setpoint = p;
    this.#changed();
  }

  /** Home, or null. */
  setHome(p) {
    this.home = p;
    this.#changed();
  }

  /** The mission's waypoints, in flying order: `[{id, n, e}]`. */
  setWaypoints(list) {
    if (JSON.stringify(list) === JSON.stringify(this.waypoints)) return;
    this.waypoints = list;
    this.#changed();
  }

  /** Forgets the track flown so far. */
  clearTrack() {
    this.track = this.vehicle ? [{ n: this.vehicle.n, e: this.vehicle.e }] : [];
    this.render();
  }

  #changed() {
    if (this.auto && this.#needsFit()) this.#fitNow();
    this.render();
  }

  #points() {
    const all = [...this.track, ...this.waypoints];
    for (const p of [this.vehicle, this.setpoint, this.home]) if (p) all.push(p);
    return all;
  }

  #bounds() {
    const pts = this.#points();
    if (pts.length === 0) return null;
    const b = { minN: Infinity, maxN: -Infinity, minE: Infinity, maxE: -Infinity };
    for (const p of pts) {
      b.minN = Math.min(b.minN, p.n); b.maxN = Math.max(b.maxN, p.n);
      b.minE = Math.min(b.minE, p.e); b.maxE = Math.max(b.maxE, p.e);
    }
    return b;
  }

  // Refit only when something is near the edge or the content has become
  // small in the view, so that the view holds still while the vehicle
  // moves within it.
  #needsFit() {
    const b = this.#bounds();
    if (!b) return false;
    const halfN = (this.height / 2 / this.view.scale) * 0.85;
    const halfE = (this.width / 2 / this.view.scale) * 0.85;
    const outside = b.minN < this.view.n - halfN || b.maxN > this.view.n + halfN
      || b.minE < this.view.e - halfE || b.maxE > this.view.e + halfE;
    const spanN = Math.max(b.maxN - b.minN, MIN_SPAN);
    const spanE = Math.max(b.maxE - b.minE, MIN_SPAN);
    const small = spanN < halfN * 2 * 0.35 && spanE < halfE * 2 * 0.35;
    return outside || small;
  }

  #fitNow() {
    const b = this.#bounds();
    if (!b) return;
    const spanN = Math.max(b.maxN - b.minN, MIN_SPAN);
    const spanE = Math.max(b.maxE - b.minE, MIN_SPAN);
    this.view.n = (b.minN + b.maxN) / 2;
    this.view.e = (b.minE + b.maxE) / 2;
    this.view.scale = Math.min((this.width * FILL) / spanE, (this.height * FILL) / spanN);
  }

  /** Redraws everything from the current view and data. */
  render() {
    const { svg, layers, view } = this;
    svg.dataset.centerN = view.n.toFixed(3);
    svg.dataset.centerE = view.e.toFixed(3);
    svg.dataset.scale = view.scale.toFixed(4);
    svg.dataset.auto = String(this.auto);
    this.#renderGrid();
    const line = (pts) => pts.map((p) => { const s = this.toScreen(p); return `${s.x.toFixed(1)},${s.y.toFixed(1)}`; }).join(' ');
    layers.track.setAttribute('points', line(this.track));
    layers.route.setAttribute('points', line(this.waypoints));
    this.#renderWaypoints();
    this.#place(layers.home, this.home);
    this.#place(layers.setpoint, this.setpoint);
    this.#place(layers.vehicle, this.vehicle, this.vehicle ? (this.vehicle.yaw * 180) / Math.PI : 0);
    if (this.vehicle) layers.vehicle.dataset.yaw = this.vehicle.yaw.toFixed(3);
    this.#renderLeg();
    const c = { x: this.width / 2, y: this.height / 2 };
    layers.crosshair.setAttribute('transform', `translate(${c.x} ${c.y})`);
  }

  #place(node, p, degrees = 0) {
    if (!p) {
      node.setAttribute('visibility', 'hidden');
      return;
    }
    const s = this.toScreen(p);
    node.setAttribute('visibility', 'visible');
    node.setAttribute('transform', `translate(${s.x.toFixed(1)} ${s.y.toFixed(1)}) rotate(${degrees.toFixed(1)})`);
    position(node, p, s);
  }

  #renderLeg() {
    const { leg } = this.layers;
    if (!this.vehicle || !this.setpoint) {
      leg.setAttribute('visibility', 'hidden');
      return;
    }
    const a = this.toScreen(this.vehicle);
    const b = this.toScreen(this.setpoint);
    leg.setAttribute('visibility', Math.hypot(a.x - b.x, a.y - b.y) > 12 ? 'visible' : 'hidden');
    leg.setAttribute('x1', a.x.toFixed(1)); leg.setAttribute('y1', a.y.toFixed(1));
    leg.setAttribute('x2', b.x.toFixed(1)); leg.setAttribute('y2', b.y.toFixed(1));
  }

  // Nodes are made once per mission and moved on each render, so that the
  // DOM does not churn at the polling rate.
  #renderWaypoints() {
    const g = this.layers.waypoints;
    if (this.drawnWaypoints !== this.waypoints) {
      g.replaceChildren();
      for (const wp of this.waypoints) {
        const node = el('g', { class: 'waypoint' }, g);
        el('circle', { r: 6 }, node);
        el('text', { x: 9, y: -8 }, node).textContent = String(wp.id);
        el('title', {}, node).textContent = `waypoint ${wp.id}: N ${metres(wp.n)}, E ${metres(wp.e)}`;
        node.dataset.id = String(wp.id);
      }
      this.drawnWaypoints = this.waypoints;
    }
    this.waypoints.forEach((wp, i) => {
      const node = g.children[i];
      const s = this.toScreen(wp);
      node.setAttribute('transform', `translate(${s.x.toFixed(1)} ${s.y.toFixed(1)})`);
      position(node, wp, s);
    });
  }

  #renderGrid() {
    const { grid, overlay } = this.layers;
    grid.replaceChildren();
    overlay.replaceChildren();
    const step = gridStep(this.view.scale, 64);
    const tl = this.toWorld(0, 0);
    const br = this.toWorld(this.width, this.height);
    for (let i = Math.ceil(tl.e / step); i * step <= br.e; i += 1) {
      const e = i * step;
      const x = this.toScreen({ n: 0, e }).x.toFixed(1);
      el('line', { x1: x, y1: 0, x2: x, y2: this.height, class: i === 0 ? 'axis' : '' }, grid);
      el('text', { x: Number(x) + 3, y: this.height - 6, class: 'label' }, grid).textContent = `${Number(e.toFixed(6))}`;
    }
    for (let i = Math.ceil(br.n / step); i * step <= tl.n; i += 1) {
      const n = i * step;
      const y = this.toScreen({ n, e: 0 }).y.toFixed(1);
      el('line', { x1: 0, y1: y, x2: this.width, y2: y, class: i === 0 ? 'axis' : '' }, grid);
      el('text', { x: 4, y: Number(y) - 4, class: 'label' }, grid).textContent = `${Number(n.toFixed(6))}`;
    }
    // North arrow and scale bar.
    const north = el('g', { class: 'north', transform: 'translate(24 30)' }, overlay);
    el('path', { d: 'M0,-14 L6,4 L0,0 L-6,4 Z' }, north);
    el('text', { x: 0, y: 18, 'text-anchor': 'middle' }, north).textContent = 'N';
    const px = step * this.view.scale;
    const bar = el('g', { class: 'scalebar', transform: `translate(${this.width - px - 16} 34)` }, overlay);
    el('path', { d: `M0,-5V0H${px.toFixed(1)}V-5` }, bar);
    el('text', { x: px / 2, y: -8, 'text-anchor': 'middle' }, bar).textContent = metres(step);
  }
}
