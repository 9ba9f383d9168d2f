// The page of `resection link --serve`: link candidates to targets by clicking.
// Plain JavaScript, no build step, nothing fetched but this server's own endpoints.
// Image coordinates follow DESIGN.md: the centre of the top-left pixel is (0, 0).
"use strict";
(() => {
  const token = new URLSearchParams(location.search).get("token") || "";
  const NS = "http://www.w3.org/2000/svg";
  const $ = (id) => document.getElementById(id);
  const st = {
    info: null, cands: null, plan: null, links: [], history: [], selCand: -1,
    selTarget: null, result: null, vb: null, planRot: 0, planMirror: false,
    raw: null, cdf: null, seq: 0, stopped: false,
  };

  async function api(path, body) {
    const opts = { headers: { "X-Link-Token": token } };
    if (body !== undefined) {
      opts.method = "POST";
      opts.headers["Content-Type"] = "application/json";
      opts.body = JSON.stringify(body);
    }
    const r = await fetch(path, opts);
    const json = (r.headers.get("Content-Type") || "").startsWith("application/json");
    const data = json ? await r.json() : await r.arrayBuffer();
    if (!r.ok) throw new Error(json ? data.error : r.statusText);
    return data;
  }

  function el(tag, attrs, parent, text) {
    const e = document.createElementNS(NS, tag);
    for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
    if (text !== undefined) e.textContent = text;
    if (parent) parent.appendChild(e);
    return e;
  }

  // ------------------------------------------------------------------ the frame
  function histogram(raw) {
    const h = new Float64Array(65536);
    let n = 0;
    for (let i = 0; i < raw.length; i++) if (raw[i] > 0) { h[raw[i]]++; n++; }
    for (let i = 1; i < h.length; i++) h[i] += h[i - 1];
    for (let i = 0; i < h.length; i++) h[i] /= Math.max(n, 1);
    return h;
  }
  function level(p) { // value at percentile p (0-100) of the finite pixels
    const q = p / 100;
    let lo = 1, hi = 65535;
    while (lo < hi) { const m = (lo + hi) >> 1; if (st.cdf[m] < q) lo = m + 1; else hi = m; }
    return lo;
  }
  function stretch() {
    const { width: W, height: H } = st.info;
    let a = level(+$("lo").value), b = level(+$("hi").value);
    if (b <= a) b = a + 1;
    const canvas = document.createElement("canvas");
    canvas.width = W; canvas.height = H;
    const ctx = canvas.getContext("2d");
    const im = ctx.createImageData(W, H);
    const px = im.data, raw = st.raw, s = 255 / (b - a);
    for (let i = 0, j = 0; i < raw.length; i++, j += 4) {
      const r = raw[i];
      if (r === 0) { px[j] = 120; px[j + 1] = 0; px[j + 2] = 120; } // masked: purple
      else { const g = Math.max(0, Math.min(255, (r - a) * s)); px[j] = px[j + 1] = px[j + 2] = g; }
      px[j + 3] = 255;
    }
    ctx.putImageData(im, 0, 0);
    $("img").setAttribute("href", canvas.toDataURL("image/png"));
  }

  // ------------------------------------------------------------------ view: zoom, pan
  const svg = $("frame");
  function setView(vb) {
    st.vb = vb;
    svg.setAttribute("viewBox", `${vb.x} ${vb.y} ${vb.w} ${vb.h}`);
    drawOverlay();
  }
  function fit() { setView({ x: -0.5, y: -0.5, w: st.info.width, h: st.info.height }); }
  function toImage(evt) {
    const p = svg.createSVGPoint();
    p.x = evt.clientX; p.y = evt.clientY;
    return p.matrixTransform(svg.getScreenCTM().inverse());
  }
  function unitsPerPixel() {
    const r = svg.getBoundingClientRect();
    return Math.max(st.vb.w / Math.max(r.width, 1), st.vb.h / Math.max(r.height, 1));
  }
  svg.addEventListener("wheel", (e) => {
    e.preventDefault();
    const p = toImage(e), k = e.deltaY < 0 ? 1 / 1.25 : 1.25, vb = st.vb;
    setView({ x: p.x - (p.x - vb.x) * k, y: p.y - (p.y - vb.y) * k, w: vb.w * k, h: vb.h * k });
  }, { passive: false });
  let drag = null;
  svg.addEventListener("mousedown", (e) => {
    if (e.button !== 0) return;
    drag = { x: e.clientX, y: e.clientY, vb: { ...st.vb }, moved: false, upp: unitsPerPixel() };
  });
  window.addEventListener("mousemove", (e) => {
    if (!drag) return;
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    if (!drag.moved && Math.hypot(dx, dy) < 4) return;
    drag.moved = true;
    setView({ ...drag.vb, x: drag.vb.x - dx * drag.upp, y: drag.vb.y - dy * drag.upp });
  });
  window.addEventListener("mouseup", (e) => {
    const d = drag; drag = null;
    if (!d || d.moved || e.target.closest("#frame") === null) return;
    clickFrame(toImage(e));
  });

  // ------------------------------------------------------------------ linking
  function nearestCandidate(p) {
    const { u, v } = st.cands;
    let best = -1, bd = Infinity;
    for (let i = 0; i < u.length; i++) {
      const d = (u[i] - p.x) ** 2 + (v[i] - p.y) ** 2;
      if (d < bd) { bd = d; best = i; }
    }
    return best;
  }
  function offerOf(key, value) {
    return ((st.result && st.result.offers) || []).find((o) => o[key] === value);
  }
  function setLinks(links) {
    st.history.push(st.links);
    st.links = links;
    solve();
  }
  function link(id, c) {
    setLinks([...st.links.filter(([k, j]) => k !== id && j !== c), [id, c]]);
  }
  function clickFrame(p) {
    const c = nearestCandidate(p);
    // the nearest candidate within 30 screen pixels (or three diameters): else a click in
    // an empty place clears the selection
    const reach = Math.max(30 * unitsPerPixel(), 3 * (st.info.diameter || 6));
    if (c < 0 || Math.hypot(st.cands.u[c] - p.x, st.cands.v[c] - p.y) > reach) {
      st.selCand = -1; draw(); return;
    }
    const offer = offerOf("candidate", c);
    if (st.selTarget !== null) { link(st.selTarget, c); st.selTarget = null; st.selCand = -1; }
    else if (offer && !st.links.some(([, j]) => j === c)) { link(offer.id, c); st.selCand = c; }
    else st.selCand = st.selCand === c ? -1 : c;
    draw();
  }
  function clickTarget(id) {
    if (st.selCand >= 0) { link(id, st.selCand); st.selCand = -1; st.selTarget = null; }
    else st.selTarget = st.selTarget === id ? null : id;
    draw();
  }
  function undo() {
    if (!st.history.length) return;
    st.links = st.history.pop();
    st.selCand = -1; st.selTarget = null;
    solve();
  }
  function deleteSelected() {
    const keep = st.links.filter(([k, j]) => k !== st.selTarget && j !== st.selCand);
    if (keep.length !== st.links.length) setLinks(keep);
    st.selCand = -1; st.selTarget = null;
    draw();
  }
  function nextTarget() {
    const ids = st.plan.ids, linked = new Set(st.links.map(([k]) => k));
    const start = st.selTarget === null ? -1 : ids.indexOf(st.selTarget);
    for (let s = 1; s <= ids.length; s++) {
      const id = ids[(start + s) % ids.length];
      if (!linked.has(id)) { st.selTarget = id; break; }
    }
    draw();
    const li = document.querySelector(`#targets li[data-id="${CSS.escape(st.selTarget)}"]`);
    if (li) li.scrollIntoView({ block: "nearest" });
  }
  function takeOffer() {
    const o = (st.selTarget !== null && offerOf("id", st.selTarget))
      || ((st.result && st.result.offers) || [])[0];
    if (o) { link(o.id, o.candidate); st.selTarget = null; }
  }
  window.addEventListener("keydown", (e) => {
    if (e.target.tagName === "INPUT") return;
    const k = e.key.toLowerCase();
    if ((k === "z" && (e.ctrlKey || e.metaKey)) || k === "u") { undo(); e.preventDefault(); }
    else if (k === "delete" || k === "backspace") { deleteSelected(); e.preventDefault(); }
    else if (k === "n" || k === "tab") { nextTarget(); e.preventDefault(); }
    else if (k === "a") takeOffer();
    else if (k === "f") fit();
    else if (k === "escape") { st.selCand = -1; st.selTarget = null; draw(); }
  });

  async function solve() {
    const seq = ++st.seq;
    document.body.dataset.pending = "1";
    draw();
    try {
      const res = await api("api/solve", { links: st.links });
      if (seq !== st.seq) return; // a newer set of links is on its way
      st.result = res;
      // the plan follows the last accepted pose (not back to the normals' view on a refusal);
      // a turn or mirror chosen for the normals' view does not carry over to the camera's
      if (res.plan && (res.status === "accepted" || st.plan.source !== "camera")) {
        if (res.plan.source !== st.plan.source) { st.planRot = 0; st.planMirror = false; }
        st.plan = res.plan;
      }
    } catch (err) {
      if (seq !== st.seq) return;
      st.result = { status: "refused", message: String(err.message), links: [], offers: [],
        predicted: [] };
    }
    document.body.dataset.pending = "0";
    draw();
  }
  async function save(quit) {
    const out = $("saved");
    try {
      const res = await api("api/save", quit ? { links: st.links, quit: true }
        : { links: st.links });
      out.className = ""; out.textContent = res.message;
      if (res.quit) {
        st.stopped = true;
        out.textContent += "; the server has stopped: this page can be closed";
        draw();
      }
    } catch (err) { out.className = "error"; out.textContent = String(err.message); }
  }

  // ------------------------------------------------------------------ drawing
  function linkInfo() {
    const m = new Map();
    for (const l of (st.result && st.result.links) || []) m.set(l.id, l);
    return m;
  }
  function visibleBox() { // the part of the image the frame's area shows, image units
    const r = svg.getBoundingClientRect(), m = svg.getScreenCTM().inverse();
    const p = svg.createSVGPoint();
    p.x = r.left; p.y = r.top; const a = p.matrixTransform(m);
    p.x = r.right; p.y = r.bottom; const b = p.matrixTransform(m);
    return { x0: a.x, y0: a.y, x1: b.x, y1: b.y };
  }
  // a label beside a point: to its right, or to its left where it would leave the frame's
  // area (the side bar would cover it)
  function label(x, y, text, cls, parent, upp, fs, side) {
    const w = 0.62 * fs * String(text).length, gap = 6 * upp, box = visibleBox();
    // a point outside the area keeps its label outside too (not half of it at the edge)
    const left = x > box.x1 ? false : x < box.x0 ? true
      : side === "left" ? x - gap - w >= box.x0 : x + gap + w > box.x1;
    const inside = x >= box.x0 && x <= box.x1 && y >= box.y0 && y <= box.y1;
    const ty = inside ? Math.min(Math.max(y, box.y0 + fs), box.y1 - 2 * upp) : y;
    return el("text", { x: left ? x - gap : x + gap, y: ty, "font-size": fs,
      "text-anchor": left ? "end" : "start", "stroke-width": 3 * upp, class: cls }, parent, text);
  }
  function drawOverlay() {
    if (!st.cands || !st.vb) return;
    const upp = unitsPerPixel(), fs = 12 * upp, lw = 1.5;
    const { u, v, diameter } = st.cands, d0 = st.info.diameter || 6;
    const info = linkInfo(), byCand = new Map(st.links.map(([k, j]) => [j, k]));
    const g = $("cands"); g.replaceChildren();
    for (let i = 0; i < u.length; i++) {
      const id = byCand.get(i), li = id !== undefined ? info.get(id) : undefined;
      let cls = "cand";
      if (id !== undefined) cls += li && li.rejected ? " rejected" : " linked";
      if (i === st.selCand) cls += " selected";
      const r = Math.max((diameter[i] || d0) / 2 + 2, 4 * upp);
      el("circle", { cx: u[i], cy: v[i], r, class: cls, "data-index": i,
        "stroke-width": i === st.selCand ? 2.5 * lw : lw, "vector-effect": "non-scaling-stroke" }, g);
    }
    const lg = $("links"); lg.replaceChildren();
    for (const [id, j] of st.links) {
      const li = info.get(id);
      const txt = li && li.residual !== null ? `${id} ${li.residual.toFixed(2)}px` : id;
      label(u[j], v[j] - 6 * upp, (li && li.rejected ? "rejected " : "") + txt,
        "label link-label" + (li && li.rejected ? " rejected" : ""), lg, upp, fs, "right");
    }
    const pg = $("preds"); pg.replaceChildren();
    const og = $("offers"); og.replaceChildren();
    if (!st.result || st.result.status !== "accepted") return;
    const s = 5 * upp;
    for (const p of st.result.predicted) {
      const grp = el("g", { class: "pred", "data-id": p.id }, pg);
      el("path", { d: `M${p.u - s},${p.v}H${p.u + s}M${p.u},${p.v - s}V${p.v + s}`,
        "stroke-width": lw, "vector-effect": "non-scaling-stroke", class: "pred" }, grp);
      label(p.u, p.v + 14 * upp, p.id, "label pred-label", grp, upp, fs, "left");
    }
    const pred = new Map(st.result.predicted.map((p) => [p.id, p]));
    for (const o of st.result.offers) {
      const p = pred.get(o.id);
      el("line", { x1: p.u, y1: p.v, x2: u[o.candidate], y2: v[o.candidate], class: "offer",
        "vector-effect": "non-scaling-stroke" }, og);
      el("circle", { cx: u[o.candidate], cy: v[o.candidate], class: "offer-hit",
        r: Math.max((diameter[o.candidate] || d0) / 2 + 4, 6 * upp), "data-offer": o.id,
        "vector-effect": "non-scaling-stroke" }, og);
    }
  }
  function planXY(x, y) {
    for (let r = 0; r < st.planRot; r++) [x, y] = [-y, x];
    return [st.planMirror ? -x : x, y];
  }
  function drawPlan() {
    const g = $("plan"); g.replaceChildren();
    const { ids, xy } = st.plan, pts = xy.map((p) => (p[0] === null ? null : planXY(p[0], p[1])));
    const ok = pts.filter((p) => p !== null);
    if (!ok.length) return;
    const xs = ok.map((p) => p[0]), ys = ok.map((p) => p[1]);
    const x0 = Math.min(...xs), x1 = Math.max(...xs), y0 = Math.min(...ys), y1 = Math.max(...ys);
    const k = Math.min(240 / Math.max(x1 - x0, 1e-12), 180 / Math.max(y1 - y0, 1e-12));
    const ox = 140 - k * (x0 + x1) / 2, oy = 112 - k * (y0 + y1) / 2;
    const info = linkInfo(), linked = new Set(st.links.map(([id]) => id));
    ids.forEach((id, i) => {
      if (pts[i] === null) return;
      const [x, y] = [ox + k * pts[i][0], oy + k * pts[i][1]];
      let cls = "plan-dot";
      if (linked.has(id)) cls += info.get(id) && info.get(id).rejected ? " rejected" : " linked";
      if (id === st.selTarget) cls += " selected";
      const c = el("circle", { cx: x, cy: y, r: 5, class: cls, "data-id": id }, g);
      c.addEventListener("click", () => clickTarget(id));
      const right = x + 6 + 5.5 * String(id).length > 298; // 9 px text: about 5.5 px a letter
      el("text", { x: right ? x - 6 : x + 6, y: y - 4, class: "plan-label",
        "text-anchor": right ? "end" : "start" }, g, id);
    });
    const turned = (st.planRot ? `, turned by ${90 * st.planRot} deg` : "")
      + (st.planMirror ? ", mirrored" : "");
    $("plan-source").textContent = st.plan.source === "camera"
      ? `as the camera sees them${turned}`
      : `no pose yet: seen along the targets' ${st.plan.source}${turned}`
        + " (turn or mirror it to match the frame)";
  }
  function drawList() {
    const ol = $("targets"), info = linkInfo(), byId = new Map(st.links);
    const offers = new Map(((st.result && st.result.offers) || []).map((o) => [o.id, o]));
    const pred = new Set(((st.result && st.result.predicted) || []).map((p) => p.id));
    ol.replaceChildren();
    for (const id of st.plan.ids) {
      const li = document.createElement("li");
      li.dataset.id = id;
      const l = info.get(id), o = offers.get(id);
      let state = "", res = "";
      if (byId.has(id)) {
        li.classList.add(l && l.rejected ? "rejected" : "linked");
        state = `#${byId.get(id)}`;
        res = l && l.rejected ? "rejected" : l && l.residual !== null
          ? `${l.residual.toFixed(2)} px` : "";
      } else if (o) { li.classList.add("offered"); state = `offer #${o.candidate}`;
        res = `${o.distance.toFixed(1)} px`; }
      else if (pred.has(id)) state = "in view";
      if (id === st.selTarget) li.classList.add("selected");
      for (const [cls, t] of [["id", id], ["state", state], ["res", res]]) {
        const s = document.createElement("span"); s.className = cls; s.textContent = t;
        li.appendChild(s);
      }
      li.addEventListener("click", () => clickTarget(id));
      ol.appendChild(li);
    }
  }
  function draw() {
    const r = st.result, status = $("status");
    status.className = r ? r.status : "";
    const need = st.info.min_links - st.links.length;
    status.textContent = r ? `${st.links.length} link(s): ${r.message}`
      : `${st.links.length} link(s): link ${Math.max(need, 0)} more for a pose`;
    if (st.selCand >= 0) status.textContent += `\ncandidate #${st.selCand} selected: click its target`;
    else if (st.selTarget !== null) status.textContent += `\ntarget ${st.selTarget} selected: click its candidate`;
    const can = !st.stopped && r && r.status === "accepted" && st.info.outputs.length > 0;
    $("save").disabled = !can;
    $("save-quit").disabled = !can;
    $("save").title = st.info.outputs.length ? `writes ${st.info.outputs.join(", ")}` : "no output named";
    drawOverlay(); drawPlan(); drawList();
  }

  // ------------------------------------------------------------------ start
  async function start() {
    st.info = await api("api/session");
    st.cands = await api("api/candidates");
    st.plan = await api("api/plan");
    st.raw = new Uint16Array(await api("api/frame"));
    st.cdf = histogram(st.raw);
    $("img").setAttribute("x", -0.5); $("img").setAttribute("y", -0.5);
    $("img").setAttribute("width", st.info.width); $("img").setAttribute("height", st.info.height);
    stretch();
    fit();
    $("lo").addEventListener("input", stretch);
    $("hi").addEventListener("input", stretch);
    $("undo").addEventListener("click", undo);
    $("fit").addEventListener("click", fit);
    $("save").addEventListener("click", () => save(false));
    $("save-quit").addEventListener("click", () => save(true));
    $("rotate").addEventListener("click", () => { st.planRot = (st.planRot + 1) % 4; draw(); });
    $("mirror").addEventListener("click", () => { st.planMirror = !st.planMirror; draw(); });
    window.addEventListener("resize", drawOverlay);
    document.title = `resection link: ${st.info.image}`;
    st.links = st.info.initial_links.map(([k, c]) => [k, c]);
    if (st.links.length) solve(); else draw();
    document.body.dataset.ready = "1";
  }
  start().catch((err) => { $("status").className = "refused"; $("status").textContent = String(err); });
})();
