/*
 * The service's web page: submit a measurement file, follow jobs (server-sent events), cancel,
 * delete, download, and open the result viewer (viewer.js) on a finished job.
 *
 * Every message from the API is shown as the API wrote it (its "detail" sentence).
 *
 * When the server needs an API key, the key typed into the page is kept for the browser tab
 * (sessionStorage) and sent as "Authorization: Bearer <key>" with every request. Browsers
 * cannot add that header to an EventSource or to a plain download link, so with a key the page
 * polls job progress instead of streaming it, and downloads through fetch.
 */
(function () {
  "use strict";

  // Browsers open at most six HTTP/1.1 connections per host, and each event stream holds
  // one for as long as its job runs: follow at most this many jobs live, poll the others.
  const MAX_STREAMS = 4;
  // How often the job list is re-read: it shows jobs submitted elsewhere, and the jobs not
  // followed by an event stream.
  const LIST_REFRESH_MS = 5000;
  const LIST_REFRESH_BUSY_MS = 2000;
  const READINESS_REFRESH_MS = 15000;
  const LIST_LIMIT = 50;
  // The form's main parameters, in the order they appear.
  const MAIN_PARAMETERS = ["method", "rotations", "n_groups", "subspace_dim", "max_iter"];
  const ACTIVE = new Set(["queued", "running"]);
  const KEY_STORAGE = "moju-api-key";

  const state = {
    jobs: new Map(), // id -> job resource
    order: [], // ids, newest first
    streams: new Map(), // id -> EventSource
    viewer: null,
    viewedId: null,
    refreshTimer: null,
  };

  const $ = (selector) => document.querySelector(selector);
  // viewer.js is loaded first (index.html) and builds elements the same way.
  const { element } = MojuViewer;

  function apiKey() {
    try {
      return sessionStorage.getItem(KEY_STORAGE) || "";
    } catch (error) {
      return "";
    }
  }

  /** Headers that carry the API key, if one was given. */
  function authHeaders() {
    const key = apiKey();
    return key ? { Authorization: `Bearer ${key}` } : {};
  }

  class ApiError extends Error {
    constructor(status, detail) {
      super(detail);
      this.status = status;
    }
  }

  /** Call the API; resolves to the decoded JSON body, rejects with the API's detail. */
  async function api(method, url, body) {
    let response;
    try {
      response = await fetch(url, {
        method, body, headers: { Accept: "application/json", ...authHeaders() },
      });
    } catch (error) {
      throw new ApiError(0, `the service did not answer (${error.message})`);
    }
    if (response.status === 204) {
      return null;
    }
    const text = await response.text();
    let data = null;
    try {
      data = text ? JSON.parse(text) : null;
    } catch (error) {
      data = null;
    }
    if (!response.ok) {
      const detail = data && typeof data.detail === "string" ? data.detail : text;
      throw new ApiError(response.status, detail || `HTTP ${response.status}`);
    }
    return data;
  }

  /** Download a file through fetch, so that the API key goes with the request. */
  async function downloadWithKey(href) {
    try {
      const response = await fetch(href, { headers: authHeaders() });
      if (!response.ok) {
        let detail = `HTTP ${response.status}`;
        try {
          detail = (await response.json()).detail || detail;
        } catch (error) {
          // not JSON: keep the status
        }
        throw new Error(detail);
      }
      const disposition = response.headers.get("content-disposition") || "";
      const match = /filename="([^"]+)"/.exec(disposition);
      const url = URL.createObjectURL(await response.blob());
      const link = element("a", { href: url, download: match ? match[1] : "" });
      document.body.append(link);
      link.click();
      link.remove();
      setTimeout(() => URL.revokeObjectURL(url), 60000);
    } catch (error) {
      showError($("#jobs-error"), error.message);
    }
  }

  function showError(node, message) {
    node.textContent = message || "";
    node.hidden = !message;
  }

  function seconds(value) {
    if (value === null || value === undefined) {
      return "?";
    }
    if (value < 60) {
      return `${value < 10 ? value.toFixed(1) : Math.round(value)} s`;
    }
    const minutes = Math.floor(value / 60);
    return `${minutes} min ${Math.round(value - 60 * minutes)} s`;
  }

  // ------------------------------------------------------------------------------------
  // The form, built from the parameter schema the API publishes

  function schemaOf(property) {
    // Optional parameters are {"anyOf": [{"type": "integer", ...}, {"type": "null"}]}.
    if (property.anyOf) {
      return property.anyOf.find((part) => part.type !== "null") || {};
    }
    return property;
  }

  async function buildForm() {
    let document_;
    try {
      document_ = await api("GET", "/openapi.json");
    } catch (error) {
      showError($("#submit-error"), `could not read the parameter schema: ${error.message}`);
      return;
    }
    const properties = document_.components.schemas.SolverParams.properties;
    for (const name of MAIN_PARAMETERS) {
      const property = properties[name];
      const input = document.getElementById(name);
      if (!property || !input) {
        continue;
      }
      const label = document.querySelector(`label[for="${name}"]`);
      if (label && property.description) {
        label.title = property.description;
        input.title = property.description;
      }
      const schema = schemaOf(property);
      if (input.tagName === "SELECT") {
        for (const value of schema.enum || []) {
          const option = element("option", { value }, value);
          if (value === property.default && name !== "rotations") {
            option.selected = true;
          }
          input.append(option);
        }
      } else {
        if (schema.minimum !== undefined) input.min = schema.minimum;
        if (schema.maximum !== undefined) input.max = schema.maximum;
        if (property.default !== null && property.default !== undefined) {
          input.placeholder = String(property.default);
        }
      }
    }
  }

  /** The parameters typed into the form; only those a user set (the rest are defaults). */
  function formParameters() {
    const params = {};
    const extra = $("#extra_params").value.trim();
    if (extra) {
      let parsed;
      try {
        parsed = JSON.parse(extra);
      } catch (error) {
        throw new Error(`More parameters: not valid JSON (${error.message})`);
      }
      if (parsed === null || typeof parsed !== "object" || Array.isArray(parsed)) {
        throw new Error('More parameters: give a JSON object such as {"seed": 1}');
      }
      Object.assign(params, parsed);
    }
    for (const name of MAIN_PARAMETERS) {
      const input = document.getElementById(name);
      const value = input.value.trim();
      if (value === "") {
        continue;
      }
      // Numbers go as numbers; anything else as typed, for the API to judge.
      params[name] = input.type === "number" && !Number.isNaN(Number(value))
        ? Number(value)
        : value;
    }
    return params;
  }

  async function submit(event) {
    event.preventDefault();
    const errorBox = $("#submit-error");
    const status = $("#submit-status");
    const button = $("#submit-button");
    showError(errorBox, "");
    const file = $("#file").files[0];
    if (!file) {
      showError(errorBox, "choose a measurement file first");
      return;
    }
    const body = new FormData();
    body.append("file", file, file.name);
    const mask = $("#mask").files[0];
    if (mask) {
      body.append("mask", mask, mask.name);
    }
    // The camera: the API refuses both together, with a message that says so.
    const focal = $("#focal").value.trim();
    if (focal !== "") {
      body.append("focal", focal);
    }
    const intrinsics = $("#intrinsics").files[0];
    if (intrinsics) {
      body.append("intrinsics", intrinsics, intrinsics.name);
    }
    try {
      body.append("params", JSON.stringify(formParameters()));
    } catch (error) {
      showError(errorBox, error.message);
      return;
    }
    button.disabled = true;
    status.textContent = `uploading ${file.name}\u2026`;
    try {
      const job = await api("POST", "/v1/jobs", body);
      status.textContent = `submitted job ${job.id}`;
      upsert(job, { first: true });
      syncStreams();
    } catch (error) {
      status.textContent = "";
      showError(errorBox, error.message);
    } finally {
      button.disabled = false;
    }
  }

  // ------------------------------------------------------------------------------------
  // The job list

  function progressCell(job) {
    const cell = element("td", { class: "progress-cell" });
    const p = job.progress;
    if (job.status === "failed") {
      cell.append(element("span", { class: "error job-error" }, job.error || "failed"));
      return cell;
    }
    if (job.status === "queued") {
      cell.append(element("span", { class: "muted" }, "waiting for a worker"));
      return cell;
    }
    if (job.status === "cancelled") {
      const where = p ? ` at iteration ${p.iteration}` : "";
      cell.append(element("span", { class: "muted" }, `cancelled${where}`));
      return cell;
    }
    if (job.status === "finished" && job.result) {
      const r = job.result;
      const total = r.timings && r.timings.total !== undefined
        ? `, ${seconds(r.timings.total)}`
        : "";
      cell.append(element("span", {}, `${r.n_iter} iterations, ${r.stop_reason}${total}`));
      for (const warning of r.warnings || []) {
        cell.append(element("div", { class: "warning" }, `warning: ${warning}`));
      }
      return cell;
    }
    if (p) {
      const bar = element("progress", { max: "1", value: String(p.fraction) });
      bar.setAttribute("aria-label", "progress");
      const parts = [p.stage];
      if (p.stage === "iterating") {
        parts.push(`iteration ${p.iteration} / ${p.max_iter}`);
      } else if (p.stage === "tracking") {
        parts.push(`frame ${p.iteration} / ${p.max_iter}`);
      }
      if (p.gap !== null && p.gap !== undefined) {
        parts.push(`gap ${p.gap.toExponential(2)}`);
      }
      // The time left is an extrapolation: only once a few steps were timed, and not as a
      // meaningless "0.0 s" (a job about to end, or a first report).
      const timed = p.stage === "tracking" ? p.iteration >= 2 : p.iteration >= 3;
      if (p.eta !== null && p.eta !== undefined && timed && p.eta >= 0.5) {
        parts.push(`about ${seconds(p.eta)} left`);
      }
      cell.append(bar, element("span", { class: "progress-text" }, parts.join(" \u00b7 ")));
    } else {
      cell.append(element("span", { class: "muted" }, "starting"));
    }
    return cell;
  }

  function actionsCell(job) {
    const cell = element("td", { class: "actions-cell" });
    if (job.status === "finished") {
      const view = element("button", { type: "button", class: "view" }, "View");
      view.addEventListener("click", () => {
        location.hash = `#view=${job.id}`;
      });
      cell.append(view);
      const downloads = [
        ["npz", `/v1/jobs/${job.id}/result?format=npz`],
        ["HDF5", `/v1/jobs/${job.id}/result?format=h5`],
        ["PLY zip", `/v1/jobs/${job.id}/frames.zip`],
      ];
      if (job.links && job.links.tracks) {
        downloads.push(["tracks", job.links.tracks]);
      }
      for (const [label, href] of downloads) {
        const link = element("a", { href, download: "", class: "download" }, label);
        link.addEventListener("click", (event) => {
          if (apiKey()) {
            event.preventDefault(); // a plain link would go without the key
            downloadWithKey(href);
          }
        });
        cell.append(link);
      }
    }
    if (ACTIVE.has(job.status)) {
      const cancel = element("button", { type: "button", class: "cancel" }, "Cancel");
      cancel.addEventListener("click", () => remove(job, "cancel"));
      cell.append(cancel);
    } else {
      const del = element("button", { type: "button", class: "delete" }, "Delete");
      del.addEventListener("click", () => remove(job, "delete"));
      cell.append(del);
    }
    return cell;
  }

  function row(job) {
    const tr = element("tr", { "data-job-id": job.id, "data-status": job.status });
    const name = job.input.filename || `${job.input.format} upload`;
    const created = new Date(job.created_at).toLocaleString();
    const jobCell = element("td", { class: "job-cell" });
    jobCell.append(
      element("div", { class: "job-name" }, name),
      element(
        "div", { class: "muted job-id", title: job.id }, `${job.id.slice(0, 8)} \u00b7 ${created}`,
      ),
    );
    const size = element("td", {}, `${job.input.frames} \u00d7 ${job.input.points}`);
    const observed = job.input.observed_fraction;
    if (typeof observed === "number" && observed < 1) {
      // Points missing from the upload: the solver fills them in.
      const text = `${(100 * observed).toFixed(1)} % observed`;
      size.append(element("div", { class: "muted observed" }, text));
    }
    const camera = job.input.camera;
    if (camera) {
      // The camera the job solves with: its focal length and where it came from.
      const [fx, fy] = [camera.K[0][0], camera.K[1][1]].map((f) => Number(f.toPrecision(6)));
      const focal = fx === fy ? `${fx} px` : `${fx} \u00d7 ${fy} px`;
      const title = `K = ${JSON.stringify(camera.K)}`;
      const text = `focal ${focal} (${camera.source})`;
      size.append(element("div", { class: "muted camera", title }, text));
    }
    const status = element("td", {});
    status.append(element("span", { class: `badge status-${job.status}` }, job.status));
    tr.append(jobCell, size, status, progressCell(job), actionsCell(job));
    return tr;
  }

  /** Record a job resource and (re)draw its row if it changed. */
  function upsert(job, { first = false } = {}) {
    const previous = state.jobs.get(job.id);
    state.jobs.set(job.id, job);
    if (!state.order.includes(job.id)) {
      if (first) {
        state.order.unshift(job.id);
      } else {
        state.order.push(job.id);
      }
    }
    const body = $("#jobs-body");
    const existing = body.querySelector(`tr[data-job-id="${job.id}"]`);
    if (existing && previous && JSON.stringify(previous) === JSON.stringify(job)) {
      return;
    }
    const fresh = row(job);
    if (existing) {
      existing.replaceWith(fresh);
    } else {
      const index = state.order.indexOf(job.id);
      const next = state.order.slice(index + 1).map((id) =>
        body.querySelector(`tr[data-job-id="${id}"]`)).find((node) => node);
      body.insertBefore(fresh, next || null);
    }
    $("#jobs-empty").hidden = state.order.length > 0;
  }

  /** Take a job off the list (deleted, or no longer among the newest LIST_LIMIT). */
  function dropRow(id) {
    state.jobs.delete(id);
    state.order = state.order.filter((other) => other !== id);
    const existing = $("#jobs-body").querySelector(`tr[data-job-id="${id}"]`);
    if (existing) {
      existing.remove();
    }
    closeStream(id);
    $("#jobs-empty").hidden = state.order.length > 0;
  }

  /** A job that no longer exists: off the list, and out of the viewer. */
  function forget(id) {
    dropRow(id);
    if (state.viewedId === id) {
      location.hash = "";
    }
  }

  async function refreshList() {
    clearTimeout(state.refreshTimer);
    try {
      const page = await api("GET", `/v1/jobs?limit=${LIST_LIMIT}&offset=0`);
      const listed = new Set(page.items.map((job) => job.id));
      for (const id of [...state.order]) {
        if (!listed.has(id)) {
          dropRow(id);
        }
      }
      state.order = page.items.map((job) => job.id);
      for (const job of page.items) {
        upsert(job);
      }
      const total = page.total > page.items.length
        ? `Showing the newest ${page.items.length} of ${page.total} jobs.`
        : "";
      $("#jobs-total").textContent = total;
      showError($("#jobs-error"), "");
    } catch (error) {
      showError($("#jobs-error"), error.message);
    }
    syncStreams();
    const unfollowed = state.order.some(
      (id) => ACTIVE.has(state.jobs.get(id).status) && !state.streams.has(id),
    );
    state.refreshTimer = setTimeout(
      refreshList, unfollowed ? LIST_REFRESH_BUSY_MS : LIST_REFRESH_MS,
    );
  }

  async function remove(job, verb) {
    const name = job.input.filename || "upload";
    if (verb === "delete" && !window.confirm(`Delete job ${job.id} (${name}) and its files?`)) {
      return;
    }
    try {
      await api("DELETE", `/v1/jobs/${job.id}`);
      showError($("#jobs-error"), "");
    } catch (error) {
      showError($("#jobs-error"), error.message);
      return;
    }
    if (verb === "delete") {
      forget(job.id);
      return;
    }
    try {
      upsert(await api("GET", `/v1/jobs/${job.id}`));
    } catch (error) {
      if (error.status === 404) {
        forget(job.id);
      } else {
        showError($("#jobs-error"), error.message);
      }
    }
  }

  // ------------------------------------------------------------------------------------
  // Live progress: one EventSource per followed job

  function closeStream(id) {
    const stream = state.streams.get(id);
    if (stream) {
      stream.close();
      state.streams.delete(id);
    }
  }

  function follow(id) {
    const stream = new EventSource(`/v1/jobs/${id}/events`);
    stream.addEventListener("progress", (event) => upsert(JSON.parse(event.data)));
    stream.addEventListener("end", (event) => {
      const job = JSON.parse(event.data);
      closeStream(id);
      if (job.deleted) {
        forget(id);
      } else {
        upsert(job);
      }
      syncStreams();
    });
    stream.addEventListener("error", () => {
      // The browser reconnects by itself unless the server refused the stream (e.g. 404:
      // the job is gone); the list refresh then tells what became of the job.
      if (stream.readyState === EventSource.CLOSED) {
        state.streams.delete(id);
      }
    });
    state.streams.set(id, stream);
  }

  /** Follow the newest active jobs live (at most MAX_STREAMS), stop following the others. */
  function syncStreams() {
    const active = state.order.filter((id) => ACTIVE.has(state.jobs.get(id).status));
    // An EventSource cannot carry the API key: with a key, the list refresh polls instead.
    const wanted = new Set(apiKey() ? [] : active.slice(0, MAX_STREAMS));
    for (const id of [...state.streams.keys()]) {
      if (!wanted.has(id)) {
        closeStream(id);
      }
    }
    for (const id of wanted) {
      if (!state.streams.has(id)) {
        follow(id);
      }
    }
  }

  // ------------------------------------------------------------------------------------
  // Readiness and the viewer

  async function refreshReadiness() {
    const line = $("#readiness");
    try {
      const ready = await api("GET", "/readyz");
      const workers = ready.workers === 1 ? "1 worker" : `${ready.workers} workers`;
      line.textContent = `Ready: ${workers} waiting for jobs.`;
      line.classList.remove("error");
    } catch (error) {
      line.textContent = `Not ready: ${error.message}`;
      line.classList.add("error");
    }
    setTimeout(refreshReadiness, READINESS_REFRESH_MS);
  }

  function openViewerFromHash() {
    const match = /^#view=([0-9a-f-]{36})$/.exec(location.hash);
    const id = match ? match[1] : null;
    if (id === state.viewedId) {
      return;
    }
    if (state.viewer) {
      state.viewer.destroy();
      state.viewer = null;
    }
    state.viewedId = id;
    const section = $("#viewer");
    section.hidden = id === null;
    if (id === null) {
      return;
    }
    const job = state.jobs.get(id);
    const name = job && job.input.filename ? ` (${job.input.filename})` : "";
    $("#viewer-title").textContent = `Result of job ${id.slice(0, 8)}${name}`;
    state.viewer = new MojuViewer.Viewer(
      $("#viewer-container"), MojuViewer.httpSource(id, undefined, authHeaders()),
    );
    state.viewer.load();
    showFirstFrame(job || id);
    section.scrollIntoView({ behavior: "smooth", block: "start" });
  }

  /** Beside the 3D shape: a video job's first frame with its tracks drawn on it. */
  async function showFirstFrame(jobOrId) {
    const figure = $("#viewer-frame");
    const image = $("#viewer-frame-image");
    figure.hidden = true;
    if (image.src.startsWith("blob:")) {
      URL.revokeObjectURL(image.src);
    }
    image.removeAttribute("src");
    try {
      // Opened from the address before the job list arrived: read the job first.
      const job = typeof jobOrId === "string" ? await api("GET", `/v1/jobs/${jobOrId}`) : jobOrId;
      if (job.input.format !== "video") {
        return;
      }
      const response = await fetch(`/v1/jobs/${job.id}/first-frame.png?overlay=tracks`, {
        headers: authHeaders(),
      });
      if (!response.ok || state.viewedId !== job.id) {
        return;
      }
      image.src = URL.createObjectURL(await response.blob());
      figure.hidden = false;
    } catch (error) {
      // The 3D view works without the frame; nothing to report.
    }
  }

  function setUpKeyField() {
    const field = $("#api-key");
    field.value = apiKey();
    field.addEventListener("change", () => {
      try {
        if (field.value.trim()) {
          sessionStorage.setItem(KEY_STORAGE, field.value.trim());
        } else {
          sessionStorage.removeItem(KEY_STORAGE);
        }
      } catch (error) {
        // storage refused (private mode): the key is not kept
      }
      state.jobs.clear();
      state.order = [];
      $("#jobs-body").replaceChildren();
      for (const id of [...state.streams.keys()]) {
        closeStream(id);
      }
      refreshList();
    });
  }

  function start() {
    setUpKeyField();
    $("#submit-form").addEventListener("submit", submit);
    $("#viewer-close").addEventListener("click", () => {
      location.hash = "";
    });
    window.addEventListener("hashchange", openViewerFromHash);
    buildForm();
    refreshReadiness();
    refreshList().then(openViewerFromHash);
  }

  start();
})();
