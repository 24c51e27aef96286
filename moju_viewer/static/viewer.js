/*
 * MoJu result viewer: the recovered shapes one frame at a time as an interactive 3D point
 * cloud (or a surface when triangles were uploaded), a frame slider and a play button,
 * points coloured by local group, by depth or by the uploaded colours, and the convergence
 * curve. When points were missing from the input, the ones the solver filled in (not observed
 * in the frame shown) are drawn dimmed, hidden or like the others, as the user chooses.
 * Drawn with plotly.js (global `Plotly`).
 *
 * The same file serves the web page of the service (data fetched from
 * /v1/jobs/{id}/viewer-data, one frame at a time) and the standalone file written by
 * `moju view` (data embedded in the file). A "source" hides the difference: an object with
 * summary() and frame(f), both returning promises of the documents built by
 * moju_viewer/data.py.
 */
(function (global) {
  "use strict";

  // Frames kept in memory: enough to play a short sequence smoothly from memory, bounded so
  // that a long sequence of 20,000-point frames cannot exhaust the tab.
  const FRAME_CACHE_SIZE = 64;
  // Milliseconds between two frames while playing (about 8 frames per second).
  const PLAY_INTERVAL_MS = 125;
  // Successive group labels get hues this far apart (the golden angle), so neighbouring
  // labels never look alike, however many groups there are.
  const GOLDEN_ANGLE = 137.508;
  // Initial view: the first frame's camera turned this many degrees right and up.
  const INITIAL_YAW = 35;
  const INITIAL_PITCH = 20;

  const COLOR_MODES = {
    group: "local group",
    depth: "depth",
    input: "uploaded colours",
  };
  // How the points not observed in a frame (filled in by the solver) are drawn.
  const FILLED_MODES = {
    dim: "dimmed",
    hide: "hidden",
    same: "like observed ones",
  };
  // Opacity of dimmed filled-in markers, and how far their mesh colours fade to white.
  const FILLED_OPACITY = 0.3;
  const FILLED_FADE = 0.7;

  /**
   * Split the shown points of a frame into the observed ones and the filled-in ones.
   * `unobserved`: positions of the filled-in points (a frame document's `unobserved`).
   * Returns {observed, filled}: arrays of positions, each in increasing order.
   */
  function splitObserved(count, unobserved) {
    const filled = Array.from(unobserved || []);
    const isFilled = new Uint8Array(count);
    for (const position of filled) {
      isFilled[position] = 1;
    }
    const observed = [];
    for (let position = 0; position < count; position += 1) {
      if (!isFilled[position]) {
        observed.push(position);
      }
    }
    return { observed, filled };
  }

  /** `#rrggbb` faded towards white by `amount` in [0, 1]. */
  function fade(color, amount) {
    const value = parseInt(color.slice(1), 16);
    const channel = (shift) => {
      const c = (value >> shift) & 255;
      return Math.round(c + (255 - c) * amount).toString(16).padStart(2, "0");
    };
    return `#${channel(16)}${channel(8)}${channel(0)}`;
  }

  async function fetchJson(url, headers = {}) {
    let response;
    try {
      response = await fetch(url, { headers });
    } catch (error) {
      throw new Error(`the service did not answer (${error.message})`);
    }
    let body = null;
    try {
      body = await response.json();
    } catch (error) {
      body = null;
    }
    if (!response.ok) {
      const detail = body && typeof body.detail === "string" ? body.detail : null;
      throw new Error(detail || `${url} answered HTTP ${response.status}`);
    }
    return body;
  }

  /** Frames of a job fetched from the service's viewer-data endpoints. */
  /** `headers`: sent with every request (the page's API key, when the server needs one). */
  function httpSource(jobId, maxPoints, headers = {}) {
    const base = `/v1/jobs/${encodeURIComponent(jobId)}/viewer-data`;
    const query = maxPoints ? `?max_points=${maxPoints}` : "";
    return {
      summary: () => fetchJson(base + query, headers),
      frame: (frame) => fetchJson(`${base}/frames/${frame}${query}`, headers),
    };
  }

  /** Frames embedded in a document {summary, frames} (the file of `moju view`). */
  function embeddedSource(documentData) {
    return {
      summary: () => Promise.resolve(documentData.summary),
      frame: (frame) => Promise.resolve(documentData.frames[frame]),
    };
  }

  function hslToHex(hue, saturation, lightness) {
    const s = saturation / 100;
    const l = lightness / 100;
    const a = s * Math.min(l, 1 - l);
    const channel = (n) => {
      const k = (n + hue / 30) % 12;
      const value = l - a * Math.max(-1, Math.min(k - 3, 9 - k, 1));
      return Math.round(255 * value).toString(16).padStart(2, "0");
    };
    return `#${channel(0)}${channel(8)}${channel(4)}`;
  }

  /** The colour of local group `label`. */
  function groupColor(label) {
    const hue = (((label * GOLDEN_ANGLE) % 360) + 360) % 360;
    return hslToHex(hue, 70, 45);
  }

  /** A new `tag` element with `attributes` and, unless null, `text` (shared with app.js). */
  function element(tag, attributes = {}, text = null) {
    const node = document.createElement(tag);
    for (const [name, value] of Object.entries(attributes)) {
      node.setAttribute(name, value);
    }
    if (text !== null) {
      node.textContent = text;
    }
    return node;
  }

  function formatCount(value) {
    return Number(value).toLocaleString("en-US");
  }

  class Viewer {
    /**
     * @param {HTMLElement} container where the viewer draws itself (emptied first)
     * @param {{summary: function, frame: function}} source where the data comes from
     */
    constructor(container, source) {
      this.container = container;
      this.source = source;
      this.summary = null;
      this.frames = new Map();
      this.current = 0;
      this.wanted = 0;
      this.playing = false;
      this.playTimer = null;
      this.destroyed = false;
      this.build();
    }

    build() {
      const c = this.container;
      c.replaceChildren();
      c.classList.add("moju-viewer");
      delete c.dataset.renderedFrame;
      this.note = element("p", { class: "moju-note" }, "Loading the result\u2026");
      this.error = element("p", { class: "moju-error error", role: "alert", hidden: "" });
      this.scene = element("div", { class: "moju-scene" });
      const controls = element("div", { class: "moju-controls" });
      this.playButton = element("button", { type: "button", class: "moju-play" }, "Play");
      this.slider = element("input", {
        type: "range", class: "moju-frame", min: "0", max: "0", value: "0", step: "1",
        "aria-label": "Frame",
      });
      this.frameLabel = element("span", { class: "moju-frame-label" }, "");
      const colorLabel = element("label", {}, "Colour by ");
      this.colorSelect = element("select", { class: "moju-color", "aria-label": "Colour by" });
      colorLabel.append(this.colorSelect);
      this.styleLabel = element("label", { hidden: "" }, "Draw ");
      this.styleSelect = element("select", { class: "moju-style", "aria-label": "Draw as" });
      this.styleSelect.append(
        element("option", { value: "mesh" }, "surface"),
        element("option", { value: "points" }, "points"),
      );
      this.styleLabel.append(this.styleSelect);
      this.filledLabel = element("label", { hidden: "" }, "Filled-in points ");
      this.filledSelect = element("select", {
        class: "moju-filled", "aria-label": "Filled-in points",
        title: "Points not observed in this frame, whose position the solver filled in",
      });
      for (const [mode, label] of Object.entries(FILLED_MODES)) {
        this.filledSelect.append(element("option", { value: mode }, label));
      }
      this.filledLabel.append(this.filledSelect);
      this.cameraButton = element(
        "button",
        { type: "button", class: "moju-camera", title: "Look along this frame's optical axis" },
        "Camera view",
      );
      controls.append(
        this.playButton, this.slider, this.frameLabel, colorLabel, this.styleLabel,
        this.filledLabel, this.cameraButton,
      );
      const curveHeading = element("div", { class: "moju-curve-heading" });
      const curveLabel = element("label", {}, "Convergence: ");
      this.curveSelect = element("select", { class: "moju-curve", "aria-label": "Curve" });
      curveLabel.append(this.curveSelect);
      this.curveNote = element("span", { class: "muted" }, "");
      curveHeading.append(curveLabel, this.curveNote);
      this.curve = element("div", { class: "moju-convergence" });
      c.append(this.note, this.error, this.scene, controls, curveHeading, this.curve);

      this.slider.addEventListener("input", () => {
        this.stop();
        this.show(Number(this.slider.value));
      });
      this.playButton.addEventListener("click", () => (this.playing ? this.stop() : this.play()));
      this.colorSelect.addEventListener("change", () => this.redraw());
      this.styleSelect.addEventListener("change", () => this.redraw());
      this.filledSelect.addEventListener("change", () => this.redraw());
      this.curveSelect.addEventListener("change", () => this.drawCurve());
      // plotly's "responsive" follows the window only: when the container narrows without a
      // window resize (the first frame of a video appearing beside it after the plots were
      // drawn), the plots would keep their width and push the page sideways.
      if (typeof ResizeObserver !== "undefined") {
        let width = 0;
        new ResizeObserver((entries) => {
          const now = Math.round(entries[0].contentRect.width);
          if (now === width) {
            return;
          }
          width = now;
          for (const plot of [this.scene, this.curve]) {
            if (plot._fullLayout && !plot.hidden) {
              Plotly.Plots.resize(plot);
            }
          }
        }).observe(c);
      }
      this.cameraButton.addEventListener("click", () => {
        if (this.summary) {
          // Kept for the next frames' layouts, so that drawing them does not undo it.
          this.camera = this.cameraOf(this.current);
          Plotly.relayout(this.scene, { "scene.camera": this.camera });
        }
      });
    }

    /** Fetch the summary, draw frame 0 and the convergence curve. */
    async load() {
      try {
        this.summary = await this.source.summary();
      } catch (error) {
        this.fail(error);
        return;
      }
      const s = this.summary;
      this.slider.max = String(Math.max(s.frames - 1, 0));
      this.playButton.disabled = s.frames < 2;
      for (const [mode, label] of Object.entries(COLOR_MODES)) {
        if (mode !== "input" || s.colors) {
          this.colorSelect.append(element("option", { value: mode }, label));
        }
      }
      this.styleLabel.hidden = !s.faces;
      // Older result files say nothing about visibility: everything counts as observed.
      this.hasMissing = typeof s.observed_fraction === "number" && s.observed_fraction < 1;
      this.filledLabel.hidden = !this.hasMissing;
      this.note.textContent = this.describe();
      this.groupColors = s.labels.map(groupColor);
      const indices = s.point_indices || s.labels.map((_, position) => position);
      this.hoverData = indices.map((point, position) => [point, s.labels[position]]);
      // A three-quarter view of frame 0 shows the relief; "Camera view" shows it head-on.
      this.camera = this.cameraOf(0, INITIAL_YAW, INITIAL_PITCH);
      this.fillCurveChoices();
      this.drawCurve();
      await this.show(0);
    }

    describe() {
      const s = this.summary;
      let text = `${formatCount(s.frames)} frames \u00d7 ${formatCount(s.points)} points, ` +
        `${formatCount(s.groups)} local groups; ${s.n_iter} iterations (${s.stop_reason}).`;
      if (s.decimated) {
        text += ` Showing ${formatCount(s.shown_points)} of ${formatCount(s.points)} points ` +
          "(a fixed random subset, the same in every frame)";
        text += s.faces === null ? "; the surface is not drawn for a subset." : ".";
      }
      if (this.hasMissing) {
        text += ` ${(100 * s.observed_fraction).toFixed(1)} % of the points were observed; ` +
          "the others are filled in by the solver (dimmed unless chosen otherwise).";
      }
      return text;
    }

    fail(error) {
      this.error.textContent = error.message || String(error);
      this.error.hidden = false;
      this.note.hidden = true;
    }

    async frame(index) {
      if (this.frames.has(index)) {
        const cached = this.frames.get(index);
        this.frames.delete(index); // re-inserted last: the map's order is least recent first
        this.frames.set(index, cached);
        return cached;
      }
      const data = await this.source.frame(index);
      this.frames.set(index, data);
      while (this.frames.size > FRAME_CACHE_SIZE) {
        this.frames.delete(this.frames.keys().next().value);
      }
      return data;
    }

    /** Draw frame `index` (the latest request wins when several are in flight). */
    async show(index) {
      this.wanted = index;
      this.slider.value = String(index);
      this.frameLabel.textContent = `frame ${index + 1} / ${this.summary.frames}`;
      let data;
      try {
        data = await this.frame(index);
      } catch (error) {
        this.stop();
        this.fail(error);
        return;
      }
      if (this.destroyed || this.wanted !== index) {
        return;
      }
      this.current = index;
      await this.draw(data);
      if (!this.destroyed && this.wanted === index) {
        this.container.dataset.renderedFrame = String(index);
      }
      if (index + 1 < this.summary.frames && !this.frames.has(index + 1)) {
        this.frame(index + 1).catch(() => {}); // prefetch; an error shows when it is drawn
      }
    }

    redraw() {
      if (this.frames.has(this.current)) {
        this.draw(this.frames.get(this.current));
      }
    }

    /** The plotly traces of one frame: observed points first, then the filled-in ones. */
    traces(data) {
      const s = this.summary;
      const mode = this.colorSelect.value || "group";
      const filledMode = this.hasMissing ? this.filledSelect.value || "dim" : "same";
      const { observed, filled } = splitObserved(data.x.length, data.unobserved);
      const filledSet = new Set(filled);
      const depthScale = {
        colorscale: "Viridis",
        cmin: s.ranges.depth[0],
        cmax: s.ranges.depth[1],
        showscale: true,
        colorbar: { title: { text: "depth" }, thickness: 14, len: 0.6 },
      };
      const baseColors = mode === "input" ? s.colors : this.groupColors;
      const hover = "point %{customdata[0]}, group %{customdata[1]}%{customdata[2]}<br>" +
        "x %{x:.4g}, y %{y:.4g}, z %{z:.4g}<extra></extra>";
      const customdata = this.hoverData.map(
        (row, position) => [...row, filledSet.has(position) ? " (filled in)" : ""],
      );
      if (s.faces && this.styleSelect.value === "mesh") {
        let faces = s.faces;
        if (filledMode === "hide") {
          faces = faces.filter((face) => !face.some((vertex) => filledSet.has(vertex)));
        }
        const mesh = {
          x: data.x,
          y: data.y,
          z: data.z,
          customdata,
          hovertemplate: hover,
          type: "mesh3d",
          i: faces.map((face) => face[0]),
          j: faces.map((face) => face[1]),
          k: faces.map((face) => face[2]),
          flatshading: false,
        };
        if (mode === "depth") {
          return [{ ...mesh, intensity: data.depth, ...depthScale }];
        }
        const colors = filledMode === "dim"
          ? baseColors.map((color, position) =>
            (filledSet.has(position) ? fade(color, FILLED_FADE) : color))
          : baseColors;
        return [{ ...mesh, vertexcolor: colors }];
      }
      const size = Math.max(1.5, Math.min(5, 7 - 1.2 * Math.log10(s.shown_points)));
      const points = (positions) => {
        const pick = (values) => positions.map((position) => values[position]);
        const marker = mode === "depth"
          ? { size, color: pick(data.depth), ...depthScale }
          : { size, color: pick(baseColors) };
        return {
          x: pick(data.x),
          y: pick(data.y),
          z: pick(data.z),
          customdata: pick(customdata),
          hovertemplate: hover,
          type: "scatter3d",
          mode: "markers",
          marker,
        };
      };
      if (filled.length === 0 || filledMode === "same") {
        return [points(observed.concat(filled).sort((a, b) => a - b))];
      }
      const traces = [points(observed)];
      if (filledMode === "dim") {
        const dimmed = points(filled);
        dimmed.opacity = FILLED_OPACITY;
        dimmed.marker = { ...dimmed.marker, showscale: false };
        traces.push(dimmed);
      }
      return traces;
    }

    /**
     * A plotly camera for frame `index`: from the camera's side of the shape, looking along
     * its optical axis r3 = r1 x r2 turned by `yaw` degrees to the right and `pitch` degrees
     * up, with image x to the right and image y downwards as in the input images (yaw = pitch
     * = 0 is the input camera's own view). The aspect ratio is proportional to the data's
     * extents, so directions in data units are directions in plotly's camera space.
     */
    cameraOf(index, yaw = 0, pitch = 0) {
      const [r1, r2] = this.summary.rotations[index];
      const r3 = [
        r1[1] * r2[2] - r1[2] * r2[1],
        r1[2] * r2[0] - r1[0] * r2[2],
        r1[0] * r2[1] - r1[1] * r2[0],
      ];
      const a = (yaw * Math.PI) / 180;
      const b = (pitch * Math.PI) / 180;
      // Unit vector from the shape's centre to the eye.
      const eye = [0, 1, 2].map((i) =>
        -r3[i] * Math.cos(a) * Math.cos(b) + r1[i] * Math.sin(a) * Math.cos(b) -
        r2[i] * Math.sin(b));
      const norm = Math.hypot(...eye) || 1;
      const distance = 1.9;
      return {
        eye: {
          x: (distance * eye[0]) / norm,
          y: (distance * eye[1]) / norm,
          z: (distance * eye[2]) / norm,
        },
        up: { x: -r2[0], y: -r2[1], z: -r2[2] },
        center: { x: 0, y: 0, z: 0 },
      };
    }

    layout() {
      const r = this.summary.ranges;
      const extents = ["x", "y", "z"].map((axis) => r[axis][1] - r[axis][0]);
      const largest = Math.max(...extents) || 1;
      const axis = (name) => ({ range: r[name], title: { text: name } });
      return {
        margin: { l: 0, r: 0, t: 0, b: 0 },
        showlegend: false,
        // The same revision on every frame: plotly keeps the camera the user chose.
        uirevision: "moju-viewer",
        scene: {
          xaxis: axis("x"),
          yaxis: axis("y"),
          zaxis: axis("z"),
          camera: this.camera,
          aspectmode: "manual",
          aspectratio: {
            x: extents[0] / largest,
            y: extents[1] / largest,
            z: extents[2] / largest,
          },
        },
      };
    }

    async draw(data) {
      await Plotly.react(this.scene, this.traces(data), this.layout(), {
        responsive: true,
        displaylogo: false,
      });
    }

    fillCurveChoices() {
      const keys = Object.keys(this.summary.history).filter(
        (key) => this.summary.history[key].length > 0,
      );
      const preferred = ["gap", "reprojection", "rho", "nuclear_norm"];
      keys.sort((a, b) => {
        const rank = (key) => (preferred.includes(key) ? preferred.indexOf(key) : 99);
        return rank(a) - rank(b) || a.localeCompare(b);
      });
      for (const key of keys) {
        this.curveSelect.append(element("option", { value: key }, key.replace(/_/g, " ")));
      }
      this.curveSelect.disabled = keys.length === 0;
    }

    drawCurve() {
      const key = this.curveSelect.value;
      if (!key) {
        this.curveNote.textContent = " this method runs no iterations.";
        this.curve.hidden = true;
        return;
      }
      const values = this.summary.history[key];
      const positive = values.every((value) => value === null || value > 0);
      const iterations = values.map((_, index) => index + 1);
      Plotly.react(
        this.curve,
        [{ type: "scatter", mode: "lines", x: iterations, y: values, name: key }],
        {
          margin: { l: 60, r: 20, t: 10, b: 40 },
          height: 240,
          xaxis: { title: { text: "iteration" } },
          yaxis: { title: { text: key.replace(/_/g, " ") }, type: positive ? "log" : "linear",
            exponentformat: "e" },
        },
        { responsive: true, displaylogo: false },
      );
    }

    play() {
      if (this.playing || !this.summary || this.summary.frames < 2) {
        return;
      }
      this.playing = true;
      this.playButton.textContent = "Pause";
      const step = async () => {
        if (!this.playing) {
          return;
        }
        const started = performance.now();
        await this.show((this.current + 1) % this.summary.frames);
        const wait = Math.max(0, PLAY_INTERVAL_MS - (performance.now() - started));
        if (this.playing) {
          this.playTimer = setTimeout(step, wait);
        }
      };
      step();
    }

    stop() {
      this.playing = false;
      this.playButton.textContent = "Play";
      clearTimeout(this.playTimer);
    }

    /** Stop playing and free the plots (before the container is reused). */
    destroy() {
      this.stop();
      this.destroyed = true;
      Plotly.purge(this.scene);
      Plotly.purge(this.curve);
      this.container.replaceChildren();
      delete this.container.dataset.renderedFrame;
    }
  }

  global.MojuViewer = {
    Viewer, httpSource, embeddedSource, groupColor, element, splitObserved, fade,
  };
})(window);
