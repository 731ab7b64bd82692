// The debrief strip of the observer page: when the session is a recording
// played again (`cutsim-server --replay FILE --live`), a strip under the 3-D
// view shows the recording's timeline — the force on the blade, each cut
// step's deviation from the planned line with the plan's band, and a tick per
// cut step — with a cursor at the time the picture shows (both come in the
// same session message as the mesh frame, so the cursor moves with the
// picture). An instructor's page (opened with `&instructor=<token>`) also
// has the controls: previous / next cut step, play / pause, speed, and a
// click on the timeline to seek. Commands go over the page's WebSocket as
// lines of the debrief's control language ("seek 12.5"); the bridge answers
// each with {"type":"control","ok":…,"field":…,"error":…}. Observers'
// pages have no controls and send nothing.

const FORCE_COLOUR = '#3cc85a';
const DEVIATION_COLOUR = '#5b8def';
// The plan's tolerance band: where a cut step's deviation is acceptable, so
// a calm green under the blue dots, not a warning colour.
const BAND_COLOUR = 'rgba(90, 190, 120, 0.16)';
const STEP_COLOUR = '#ebb91e';
const CURSOR_COLOUR = '#ffffff';
const SPEEDS = [0.25, 0.5, 1, 2, 4];

/** A finite number from a protobuf JSON value (numbers, or strings for 64-bit), else 0. */
function num(value) {
  const n = typeof value === 'string' ? Number(value) : value;
  return typeof n === 'number' && Number.isFinite(n) ? n : 0;
}

/** A list of finite numbers, at most 4096 long (as the viewer checks). */
function numbers(value) {
  return Array.isArray(value) ? value.slice(0, 4096).map(num) : [];
}

function el(tag, attrs = {}, text = '') {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text) e.textContent = text;
  return e;
}

export class Debrief {
  /**
   * @param {{instructor: boolean, onLayout: () => void}} options `onLayout`
   *     runs when the strip appears (the 3-D view gets shorter).
   */
  constructor({ instructor, onLayout }) {
    this.instructor = instructor;
    this.onLayout = onLayout;
    this.socket = null;
    this.state = null;     // the latest DebriefState
    this.timeline = null;  // the latest timeline (sent about once a second)
    this.shown = false;
    this.build();
  }

  build() {
    this.root = el('section', { id: 'debrief', hidden: '', 'aria-label': 'Debrief of a recorded session' });
    const bar = el('div', { class: 'debrief-bar' });
    this.title = el('span', { class: 'debrief-title' }, 'debrief');
    this.clock = el('span', { id: 'debrief-clock' }, '–');
    bar.append(this.title);
    if (this.instructor) {
      this.prev = el('button', { id: 'debrief-prev', title: 'previous cut step' }, '◀ cut');
      this.play = el('button', { id: 'debrief-play', title: 'play / pause' }, '■ pause');
      this.next = el('button', { id: 'debrief-next', title: 'next cut step' }, 'cut ▶');
      this.speed = el('select', { id: 'debrief-speed', title: 'speed × real time' });
      for (const s of SPEEDS) this.speed.append(el('option', { value: String(s) }, `${s}×`));
      this.speed.value = '1';
      this.prev.addEventListener('click', () => this.send('prev'));
      this.next.addEventListener('click', () => this.send('next'));
      this.play.addEventListener('click', () => this.send(this.state?.paused ? 'play' : 'pause'));
      this.speed.addEventListener('change', () => this.send(`speed ${this.speed.value}`));
      bar.append(this.prev, this.play, this.next, this.speed);
    } else {
      bar.append(el('span', { class: 'debrief-readonly' }, 'watching (the instructor steers)'));
    }
    bar.append(this.clock);
    this.reply = el('span', { id: 'debrief-reply', 'aria-live': 'polite' });
    bar.append(this.reply);
    this.canvas = el('canvas', { id: 'debrief-timeline', 'aria-label': 'Force, deviation and cut steps over the recording' });
    if (this.instructor) {
      this.canvas.classList.add('seekable');
      this.canvas.addEventListener('click', (event) => {
        if (!this.timeline || this.duration() <= 0) return;
        const rect = this.canvas.getBoundingClientRect();
        const x = (event.clientX - rect.left - this.plotLeft()) / (rect.width - this.plotLeft() - 8);
        const t = Math.min(Math.max(x, 0), 1) * this.duration();
        this.send(`seek ${t.toFixed(3)}`);
      });
    }
    this.root.append(bar, this.canvas);
    document.body.append(this.root);
    window.addEventListener('resize', () => this.draw());
  }

  setSocket(socket) {
    this.socket = socket;
  }

  send(line) {
    if (!this.socket || this.socket.readyState !== WebSocket.OPEN) {
      this.showReply(false, 'not connected');
      return;
    }
    this.socket.send(line);
  }

  /** The bridge's answer to a command. */
  onReply(message) {
    if (message.ok) this.showReply(true, `sent: ${message.command}`);
    else this.showReply(false, `${message.field}: ${message.error}`);
  }

  showReply(ok, text) {
    this.reply.textContent = String(text).slice(0, 200);
    this.reply.className = ok ? 'ok' : 'refused';
  }

  duration() {
    return num(this.state?.duration) || num(this.timeline?.duration);
  }

  /** A session message's `observed.debrief` (absent: not a debrief). */
  update(debrief) {
    if (!debrief || typeof debrief !== 'object') return;
    this.state = {
      position: num(debrief.position),
      duration: num(debrief.duration),
      paused: debrief.paused === true,
      speed: num(debrief.speed) || 1,
      lastCommand: typeof debrief.lastCommand === 'string' ? debrief.lastCommand : '',
    };
    const t = debrief.timeline;
    if (t && typeof t === 'object') {
      const forceT = numbers(t.forceT);
      const cutT = numbers(t.cutT);
      this.timeline = {
        duration: num(t.duration),
        forceT,
        forceN: numbers(t.forceN).slice(0, forceT.length),
        cutT,
        cutDeviation: numbers(t.cutDeviation).slice(0, cutT.length),
        stepT: numbers(t.stepT),
        tolerance: num(t.tolerance),
      };
    }
    if (!this.shown) {
      this.shown = true;
      this.root.hidden = false;
      document.body.classList.add('debriefing');
      this.onLayout();
    }
    this.clock.textContent = `${this.state.position.toFixed(2)} / ${this.state.duration.toFixed(2)} s` +
      `${this.state.paused ? ' · paused' : ''} · ${this.state.speed}×`;
    if (this.instructor) {
      this.play.textContent = this.state.paused ? '▶ play' : '■ pause';
      if (document.activeElement !== this.speed) this.speed.value = String(this.state.speed);
    }
    this.draw();
  }

  plotLeft() {
    return 44;
  }

  /** Force on top, deviation below, cut-step ticks, and the cursor. */
  draw() {
    if (!this.shown) return;
    const c = this.canvas;
    const dpr = window.devicePixelRatio || 1;
    const w = c.clientWidth;
    const h = c.clientHeight;
    if (c.width !== Math.round(w * dpr) || c.height !== Math.round(h * dpr)) {
      c.width = Math.round(w * dpr);
      c.height = Math.round(h * dpr);
    }
    const g = c.getContext('2d');
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    g.clearRect(0, 0, w, h);
    g.fillStyle = '#14171f';
    g.fillRect(0, 0, w, h);
    const left = this.plotLeft();
    const right = w - 8;
    const duration = this.duration();
    if (duration <= 0) return;
    const X = (t) => left + (right - left) * Math.min(Math.max(t / duration, 0), 1);
    const forceTop = 6;
    const forceBottom = h * 0.55;
    const devTop = forceBottom + 8;
    const devBottom = h - 14;
    g.font = '10px system-ui, sans-serif';
    g.fillStyle = '#9aa1b2';
    g.fillText('|F| N', 4, forceTop + 10);
    g.fillText('dev mm', 4, devTop + 10);
    const tl = this.timeline;
    if (tl) {
      // The force: the largest |f| of each span, as a filled line.
      let fMax = 0;
      for (const f of tl.forceN) fMax = Math.max(fMax, f);
      fMax = fMax > 0 ? fMax * 1.1 : 1;
      g.fillStyle = '#9aa1b2';
      g.fillText(fMax.toPrecision(2), 4, forceTop + 22);
      g.beginPath();
      g.moveTo(X(0), forceBottom);
      tl.forceT.forEach((t, i) => g.lineTo(X(t), forceBottom - (forceBottom - forceTop) * (tl.forceN[i] / fMax)));
      g.lineTo(X(duration), forceBottom);
      g.closePath();
      g.fillStyle = 'rgba(60, 200, 90, 0.25)';
      g.fill();
      g.strokeStyle = FORCE_COLOUR;
      g.lineWidth = 1.5;
      g.beginPath();
      tl.forceT.forEach((t, i) => {
        const y = forceBottom - (forceBottom - forceTop) * (tl.forceN[i] / fMax);
        if (i === 0) g.moveTo(X(t), y);
        else g.lineTo(X(t), y);
      });
      g.stroke();
      // The deviation of each scored cut step, over the plan's band.
      let dMax = tl.tolerance * 1.5;
      for (const d of tl.cutDeviation) dMax = Math.max(dMax, d * 1.1);
      dMax = dMax > 0 ? dMax : 0.001;
      const Y = (d) => devBottom - (devBottom - devTop) * Math.min(d / dMax, 1);
      if (tl.tolerance > 0) {
        g.fillStyle = BAND_COLOUR;
        g.fillRect(left, Y(tl.tolerance), right - left, devBottom - Y(tl.tolerance));
      }
      g.fillStyle = DEVIATION_COLOUR;
      tl.cutT.forEach((t, i) => {
        g.beginPath();
        g.arc(X(t), Y(tl.cutDeviation[i]), 2.5, 0, 2 * Math.PI);
        g.fill();
      });
      g.fillStyle = '#9aa1b2';
      g.fillText((1e3 * dMax).toPrecision(2), 4, devTop + 22);
      // A tick per cut step along the bottom.
      g.strokeStyle = STEP_COLOUR;
      g.lineWidth = 2;
      for (const t of tl.stepT) {
        g.beginPath();
        g.moveTo(X(t), h - 12);
        g.lineTo(X(t), h - 2);
        g.stroke();
      }
    }
    // Seconds along the axis.
    g.fillStyle = '#9aa1b2';
    const stepS = duration > 120 ? 30 : duration > 30 ? 10 : duration > 8 ? 2 : 0.5;
    for (let t = 0; t <= duration + 1e-9; t += stepS) g.fillText(`${+t.toFixed(1)}`, X(t) + 2, h - 3);
    // The cursor: the time the picture shows.
    const x = X(this.state?.position ?? 0);
    g.strokeStyle = CURSOR_COLOUR;
    g.lineWidth = 2;
    g.beginPath();
    g.moveTo(x, 2);
    g.lineTo(x, h - 2);
    g.stroke();
    g.fillStyle = CURSOR_COLOUR;
    g.beginPath();
    g.moveTo(x - 5, 0);
    g.lineTo(x + 5, 0);
    g.lineTo(x, 7);
    g.closePath();
    g.fill();
  }
}
