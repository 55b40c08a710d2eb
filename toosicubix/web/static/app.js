// ToosiCubix annotate: the page. Plain JavaScript, no build step; every change goes through the JSON API
// (POST /api/images/<i>/edit) and the server answers with the image's vehicles, fits, cuboids and targets.
"use strict";

const HOTKEYS = {
  "1": ["point", "wheel-front-left"], "2": ["point", "wheel-front-right"],
  "3": ["point", "wheel-rear-left"], "4": ["point", "wheel-rear-right"],
  "5": ["point", "edge-front-left"], "6": ["point", "edge-front-right"],
  "7": ["point", "edge-rear-left"], "8": ["point", "edge-rear-right"],
  "c": ["point", "front-center"], "v": ["point", "rear-center"], "t": ["point", "top-center"],
  "l": ["symmetry", "front"], "k": ["symmetry", "rear"], "o": ["symmetry", "roof"],
  "a": ["direction", "forward"], "w": ["direction", "leftward"],
};
const CLICK_NAMES = { symmetry: ["left one", "right one"], direction: ["tail", "head"] };
// Kinds named by one click: a point part, or a keypoint of the mapping the page was started with (--mapping).
const oneClick = (kind) => kind === "point" || kind === "keypoint";
const partLabel = (kind, name) => (oneClick(kind) ? name : `${kind} ${name}`);

// In a sequence the selection is a vehicle (state.vehicle) or a track's prediction (state.prediction), never both.
const state = {
  session: null, index: 0, view: null, revision: 0, vehicle: null, prediction: null, preferPrediction: false,
  armed: null, pending: [], selectedPart: null, lastAuto: null, image: new Image(), zoom: 1, panX: 0, panY: 0,
  mode: "click", drag: null, drawn: [],
  // The click a name chosen now goes to (click first, then choose): its index, or null (a name chosen now arms the
  // next click instead: choose first, then click). namingUv: that click's first point (to tell it is still that
  // click after an edit); renaming: whether it is a named click being renamed (r), not one waiting for a name.
  naming: null, namingUv: null, renaming: false,
};
// A track's colour: its number's (a name "<sequence>-<k>"), else its name's hash. No red (the front face), magenta
// (residuals), yellow (targets) or orange (unnamed clicks).
const TRACK_COLOURS = ["#38d9ff", "#69f0ae", "#b388ff", "#ff80ab", "#8c9eff", "#a7ffeb", "#c6ff00", "#80d8ff"];
// A vehicle's cuboid colour: a road user of a class with a palette of its own (a pedestrian, a cyclist, ...) in its
// class's colour, as the server gives it (the colours render draws it in), else its track's.
function vehicleColour(v) {
  return v.colour || trackColour(v.track);
}
function trackColour(track) {
  if (!track) return "#38d9ff";
  const m = /(\d+)$/.exec(track);
  let k = m ? Number(m[1]) : [...track].reduce((h, c) => (h * 31 + c.charCodeAt(0)) >>> 0, 7);
  return TRACK_COLOURS[k % TRACK_COLOURS.length];
}
const $ = (id) => document.getElementById(id);
const canvas = $("canvas");
const ctx = canvas.getContext("2d");

function say(text, error = false) {
  $("message").textContent = text;
  $("message").title = text;  // the whole of it, where two lines cut it
  $("message").className = error ? "error" : "";
}

async function api(method, path, body) {
  const options = { method, headers: {} };
  if (body !== undefined) {
    options.body = JSON.stringify(body);
    options.headers["Content-Type"] = "application/json";
  }
  const response = await fetch(path, options);
  const doc = await response.json();
  return { status: response.status, doc };
}

// -- loading -----------------------------------------------------------------------------------------------

async function start() {
  const { doc } = await api("GET", "/api/session");
  state.session = doc;
  state.revision = doc.revision;
  const select = $("prototype");
  for (const p of doc.prototypes) {
    const option = document.createElement("option");
    option.value = option.textContent = p;
    select.appendChild(option);
  }
  select.value = doc.prototype;
  $("keypoint-filter").addEventListener("input", buildPalette);
  $("keypoint-filter").addEventListener("keydown", (e) => {  // Enter: name the next click the first match
    const first = $("keypoints").querySelector("button");
    if (e.key === "Enter" && first) { e.target.blur(); arm(["keypoint", first.dataset.name]); }
  });
  buildPalette();
  // A reload opens where the person was (this tab's last image of this file), else on the first image.
  const saved = sessionStorage.getItem(placeKey());  // null, or the index as text
  const place = saved === null ? NaN : Number(saved);
  await showImage(Number.isInteger(place) && place >= 0 && place < doc.images.length ? place : doc.order[0]);
}

// Where this tab remembers its image of this annotation file across a reload.
const placeKey = () => `toosicubix:image:${state.session.file}:${state.session.images.length}`;

async function showImage(index) {
  const n = state.session.images.length;
  state.index = (index + n) % n;
  sessionStorage.setItem(placeKey(), String(state.index));
  state.lastAuto = null;
  say("");  // what was said was about the image left
  state.vehicle = null;
  state.prediction = null;
  state.preferPrediction = true;  // a frame opens on its first prediction, if it has one: Enter confirms it
  state.pending = [];
  state.selectedPart = null;
  await loadView();
  await new Promise((resolve) => {
    state.image.onload = resolve;
    state.image.onerror = resolve;
    state.image.src = `/images/${state.index}`;
  });
  fitToView();
  const v = currentVehicle();
  say(state.naming !== null && v ? namingPrompt(v, state.naming) : "");
}

async function loadView() {
  const { status, doc } = await api("GET", `/api/images/${state.index}`);
  if (status !== 200) { say(doc.error, true); return; }
  applyView(doc);
}

// Step through the images in the session's order (a sequence's frames in frame order).
function step(delta) {
  const order = state.session.order;
  const n = order.length;
  return showImage(order[(order.indexOf(state.index) + delta + n) % n]);
}

function applyView(doc) {
  state.view = doc;
  state.revision = doc.revision;
  const ids = doc.vehicles.map((v) => v.id);
  const tracks = doc.predictions.map((p) => p.track);
  if (state.prediction !== null && !tracks.includes(state.prediction)) state.prediction = null;
  if (state.prediction !== null) state.vehicle = null;
  else if (!ids.includes(state.vehicle)) {
    state.vehicle = null;
    if (state.preferPrediction && tracks.length) state.prediction = tracks[0];
    else if (ids.length) state.vehicle = ids[ids.length - 1];
  }
  state.preferPrediction = false;
  followNaming();
  const a = state.lastAuto;  // x takes its runner-up only while the click still has the page's name
  const named = a && doc.vehicles.find((v) => v.id === a.vehicle);
  const p = named && named.parts[a.part];
  if (a && (!p || !p.auto || p.name !== a.name)) state.lastAuto = null;
  header();
  render();
}

// The click the next name chosen goes to (state.naming), set and remembered by its first point.
function setNaming(part, renaming = false) {
  const v = currentVehicle();
  const p = part !== null && v ? v.parts[part] : null;
  state.naming = p ? part : null;
  state.namingUv = p ? [...p.uv[0]] : null;
  state.renaming = Boolean(p) && renaming;
}

// Keep state.naming in step with the view (after any answer of the server, a reload of the page, a frame change, an
// undo or delete, another vehicle selected): the same click while it is there (and, unless it is being renamed, still
// unnamed), else the selected vehicle's oldest click that waits for a name (the server keeps them, with the names
// that fit), else none. A name chosen first (state.armed) waits for the next click instead.
function followNaming() {
  const v = currentVehicle();
  if (state.naming !== null && v && state.namingUv) {
    const [u, w] = state.namingUv;
    const same = v.parts.find((p) => p.uv[0][0] === u && p.uv[0][1] === w);
    if (same && (state.renaming || !same.name)) { setNaming(same.index, state.renaming); return; }
  }
  const waiting = v && !state.armed ? v.parts.find((p) => !p.name) : undefined;
  setNaming(waiting ? waiting.index : null);
}

// How a click is numbered for people: from 1, as the Clicks list numbers them (the API's part indices are from 0).
// A click is one entry of that list (a pair's two points are one click), named or waiting for a name.
const clickNumber = (k) => k + 1;
const count = (n, word) => `${n} ${word}${n === 1 ? "" : "s"}`;
// A vehicle's clicks, as the page counts them everywhere.
const clickCount = (v) => count(v.parts.length, "click") + (v.unnamed ? ` (${v.unnamed} waiting for a name)` : "");

// The question the page asks about a click waiting for a name.
function namingPrompt(v, k) {
  const part = v.parts[k];
  const first = part.choices && part.choices.length ? part.choices[0] : null;
  if (first && first.far) {  // placed, but no part of the fitted vehicle is where the click is
    return `which part is click ${clickNumber(k)}? It is far from every part of the fitted vehicle (off the ` +
      "vehicle, or a name given wrong): choose below if it is one, or press Delete";
  }
  if (classKeypoints() && !first) {  // a road user's clicks are named by the page only once its named ones fit
    return `which keypoint is click ${clickNumber(k)}? The page names a ${v.prototype}'s clicks once its named ` +
      "ones fit: choose it under Keypoints";
  }
  return `which part is click ${clickNumber(k)}? ` + (first && first.probability > 0.3 ?
    "The page is not sure: choose below, or press its key" :
    "Nothing places the vehicle yet (a box or a named click would): choose below, or press its key");
}

// How a click is named by hand: a part's key or the palette, or a road user's keypoints.
function howToName() {
  return classKeypoints() ? "choose its keypoint below or under Keypoints" :
    "press a part's key, or choose below or in the palette";
}

function header() {
  const doc = state.view;
  const im = state.session.images[state.index];
  const tracks = $("tracks");
  tracks.textContent = "";
  $("sequence-tools").hidden = doc.sequence === null;
  if (doc.sequence === null) {
    $("image-name").textContent = `${im.id}  (${state.index + 1} / ${state.session.images.length})`;
    return;
  }
  const frames = state.session.images.filter((i) => i.sequence === doc.sequence).sort((a, b) => a.frame - b.frame);
  const position = frames.findIndex((i) => i.index === state.index) + 1;
  $("image-name").textContent = `sequence ${doc.sequence}, frame ${doc.frame} (${position} of ${frames.length})`;
  $("image-name").title = im.id;
  for (const t of doc.tracks) {  // how each track's pose on this frame is determined now
    const span = document.createElement("span");
    span.textContent = `${t.track} ${t.pose_from}`;
    span.style.color = trackColour(t.track);
    span.className = t.pose_from;
    tracks.appendChild(span);
  }
  $("confirm").disabled = $("dismiss").disabled = state.prediction === null;
}

// -- changes -----------------------------------------------------------------------------------------------

// One change through the API. Done, the message is cleared (or says what happened on the way): the caller says
// what the change did, so the message never describes a state before it.
async function edit(change, retryable = false) {
  let note = "";
  for (let attempt = 0; attempt < 5; attempt++) {
    const { status, doc } = await api("POST", `/api/images/${state.index}/edit`,
      { revision: state.revision, ...change });
    if (status === 200) {
      say(note);
      applyView(doc);
      return doc;
    }
    if (status === 422 && attempt < 2) {  // its refit ran out of time (a busy machine): nothing was written, send again
      say("the fit is taking longer than usual: trying again");
      continue;
    }
    if (status === 409 && retryable && doc.error.startsWith("stale revision")) {
      await loadView();  // another page changed the file: take its state, then add this click again
      note = "another page changed the annotations: reloaded, your click was added again";
      continue;
    }
    if (status === 409) await loadView();
    say(doc.error, true);
    // Another program (a second page's server) changed the files: this page continues only from them, on request.
    if (status === 409 && doc.error.includes("changed on disk")) $("reload").hidden = false;
    return null;
  }
  say("the annotations keep changing under this page; the click was not added", true);
  return null;
}

function currentVehicle() {
  return state.view && state.view.vehicles.find((v) => v.id === state.vehicle);
}

// The prototype the palette is for: the selected vehicle's, else the one a new vehicle gets.
function palettePrototype() {
  const v = currentVehicle();
  return v ? v.prototype : $("prototype").value;
}

// The keypoints of that prototype's own class (a pedestrian's COCO keypoints), or null for the cuboid parts.
function classKeypoints() {
  return (state.session.class_keypoints || {})[palettePrototype()] || null;
}

function currentPrediction() {
  return state.view && state.view.predictions.find((p) => p.track === state.prediction);
}

function select(vehicle, prediction = null) {
  state.vehicle = prediction === null ? vehicle : null;
  state.prediction = prediction;
  state.selectedPart = null;
  setNaming(null);  // a rename started on the vehicle before ends; a click of the selected one that waits is asked
  followNaming();
  buildPalette();
  header();
  render();
}

// A new vehicle: of the given track (a prediction's), else a new one (a new track, in a sequence).
async function newVehicle(box2d, track = null) {
  const change = { op: "add_vehicle" };
  if (track !== null) change.track = track;
  else change.prototype = $("prototype").value;
  if (box2d) change.box2d = box2d;
  const doc = await edit(change);
  if (doc) {
    select(doc.vehicle);
    say(`vehicle ${doc.vehicle} added` + (doc.track ? ` (track ${doc.track})` : ""));
  }
  return doc;
}

// After a prediction is confirmed or dismissed: the next one, else the given vehicle.
function selectNext(vehicle) {
  const next = state.view.predictions.length ? state.view.predictions[0].track : null;
  select(vehicle, next);
  return next;
}

async function confirmPrediction() {
  const track = state.prediction;
  if (track === null) { say("no prediction selected (Tab selects one)", true); return; }
  const doc = await edit({ op: "confirm_prediction", track });
  if (!doc) return;
  const next = selectNext(doc.vehicle);
  say(`track ${track} confirmed on this frame (its pose interpolated from the track)` +
      (next ? `; next: ${next} (Enter)` : ""));
}

async function dismissPrediction() {
  const track = state.prediction;
  if (track === null) { say("no prediction selected", true); return; }
  const doc = await edit({ op: "dismiss_prediction", track });
  if (!doc) return;
  const ids = doc.vehicles.map((v) => v.id);
  selectNext(ids.length ? ids[ids.length - 1] : null);
  say(`track ${track} dismissed on this frame (not saved to the annotation file; u undoes)`);
}

// Tab: the next vehicle or prediction of the image.
function cycleSelection(delta) {
  const items = [...state.view.vehicles.map((v) => [v.id, null]),
    ...state.view.predictions.map((p) => [null, p.track])];
  if (!items.length) return;
  const at = items.findIndex(([v, p]) => (p !== null ? p === state.prediction : v === state.vehicle));
  const [v, p] = items[(at + delta + items.length) % items.length];
  select(v, p);
  say(p !== null ? `prediction ${p}: Enter confirms, b draws its box, a click starts its parts, x dismisses`
    : `vehicle ${v}`);
}

async function addClick(uv) {
  if (!currentVehicle()) await newVehicle(null, state.prediction);
  if (!currentVehicle()) return;
  if (state.armed && !oneClick(state.armed[0])) {
    state.pending.push(uv);
    if (state.pending.length < 2) {
      say(`${state.armed[0]} ${state.armed[1]}: now click the ${CLICK_NAMES[state.armed[0]][1]}` + sides(state.armed));
      render();
      return;
    }
  }
  const change = { op: "add_click", vehicle: state.vehicle };
  if (state.armed) {
    change.kind = state.armed[0];
    change.name = state.armed[1];
    change.uv = oneClick(state.armed[0]) ? [uv] : state.pending;
  } else {
    change.uv = [uv];
  }
  state.pending = [];
  const armed = state.armed;
  state.armed = null;
  setNaming(null);
  const doc = await edit(change, true);
  buildPalette();
  if (!doc) return;
  state.selectedPart = doc.part;
  const auto = doc.auto_named.filter((a) => a.vehicle === state.vehicle);
  const mine = currentVehicle().parts[doc.part];
  if (armed) {
    say(`${partLabel(armed[0], armed[1])} added (you chose the name first)` + alsoNamed(doc, doc.part));
  } else if (auto.some((a) => a.part === doc.part)) {
    state.lastAuto = auto.find((a) => a.part === doc.part);
    const a = state.lastAuto;
    const from = a.how === "prior" ? "the prior cuboid (no fit yet)" : "the fit";
    const sure = a.probability !== null && a.probability !== undefined ? `, ${Math.round(100 * a.probability)} % sure`
      : ` (${a.distance_px.toFixed(0)} px from its place)`;
    say(`the page named it ${a.name}, from ${from}${sure}` +
        (a.runner_up ? `; wrong? press x for ${a.runner_up}, or pick another below` : ""));
  } else {
    setNaming(doc.part);  // the page did not name it: the next name chosen goes to it
    say(namingPrompt(currentVehicle(), doc.part));
  }
  render();
}

// The name chosen (hotkey, palette or one of the page's choices) for the click being named (state.naming). A name
// another click of the vehicle holds is swapped: that click takes this one's name (one edit, u undoes it).
async function renameClick(kind, name) {
  const part = state.naming;
  const v = currentVehicle();
  const own = v.parts[part];
  const holder = v.parts.find((p) => p.index !== part && p.kind === kind && p.name === name);
  setNaming(null);
  const doc = await edit({ op: "rename", vehicle: state.vehicle, part, kind, name, swap: true });
  if (doc) {
    state.selectedPart = part;
    const swapped = holder ? `; click ${clickNumber(holder.index)}, which had it, is now ` +
      (own.name ? partLabel(own.kind, own.name) : "unnamed") + " (names swapped: u undoes)" : "";
    say(`click ${clickNumber(part)} named ${partLabel(kind, name)}${swapped}` + alsoNamed(doc, part) +
      (state.naming !== null ? `; click ${clickNumber(state.naming)} waits for a name` : ""));
    render();
  }
}

// The other clicks of the vehicle the page named in the same edit (a name given lets it place the vehicle and name
// clicks that waited), said after what the person did: "; the page named click 1 wheel-rear-right".
function alsoNamed(doc, except) {
  const others = doc.auto_named.filter((a) => a.vehicle === state.vehicle && a.part !== except);
  return others.map((a) => `; the page named click ${clickNumber(a.part)} ${a.name}`).join("");
}

// r (or a click's rename button): the next name chosen renames the selected click.
function startRename(part) {
  const v = currentVehicle();
  if (!v || part === null || part === undefined || !v.parts[part]) { say("select a click first (click it)", true); return; }
  state.selectedPart = part;
  state.armed = null;
  setNaming(part, true);
  say(`rename click ${clickNumber(part)}: ${howToName()} (Esc: keep its name)`);
  buildPalette();
  render();
}

// s: the vehicle's own left and right swapped in its named clicks (one edit; u undoes it).
// u, Ctrl+Z or the undo button: the image's last change taken back, said so (and a click waiting for a name asked).
async function undo() {
  const doc = await edit({ op: "undo" });
  if (!doc) return;
  const v = currentVehicle();
  say("undone: the last change on this image is taken back (u again: the one before)" +
    (state.naming !== null && v ? `; ${namingPrompt(v, state.naming)}` : ""));
}

// Delete: the selected click removed, said so.
async function deleteClick() {
  const v = currentVehicle();
  const part = v.parts[state.selectedPart];
  const doc = await edit({ op: "delete_click", vehicle: state.vehicle, part: state.selectedPart });
  state.selectedPart = null;
  if (doc) {
    say(`click ${clickNumber(part.index)} (${part.name ? partLabel(part.kind, part.name) : "unnamed"}) deleted: ` +
      "u brings it back");
  }
  render();
}

async function swapSides() {
  const v = currentVehicle();
  if (!v) { say("no vehicle selected", true); return; }
  const doc = await edit({ op: "swap_sides", vehicle: v.id });
  if (doc) say(`left and right swapped in ${doc.swapped} click(s) of vehicle ${v.id} (u undoes)` +
    (doc.unpaired.length ? `; the mapping has no keypoint at the mirror place of ${doc.unpaired.join(", ")}: ` +
      "rename those yourself" : ""));
}

async function takeRunnerUp() {
  const a = state.lastAuto;
  if (!a || !a.runner_up) { say("no auto-named click to change", true); return; }
  const doc = await edit({ op: "rename", vehicle: a.vehicle, part: a.part, kind: a.runner_up_kind, name: a.runner_up });
  if (doc) { say(`renamed to ${a.runner_up}`); state.lastAuto = null; }
}

// -- palette and panels ----------------------------------------------------------------------------------------

function buildPalette() {
  const palette = $("palette");
  palette.textContent = "";
  const keys = {};
  for (const [key, [kind, name]] of Object.entries(HOTKEYS)) keys[`${kind} ${name}`] = key;
  const v = currentVehicle();
  const clicked = new Set(v ? v.parts.map((p) => `${p.kind} ${p.name}`) : []);
  // A road user with keypoints of its own (a pedestrian) is clicked on those: no cuboid parts, no car diagram.
  const own = classKeypoints();
  const keypoints = own || state.session.keypoints;
  $("parts-section").hidden = $("palette-section").hidden = own !== null;
  $("keypoint-section").hidden = !keypoints.length;
  $("mapping-name").textContent = own ? `a ${palettePrototype()}` : state.session.mapping || "";
  $("keypoint-filter").placeholder = `filter, e.g. ${own ? own[own.length - 1].replaceAll("_", " ") : "left rear light"}`;
  for (const [kind, entry] of own ? [] : Object.entries(state.session.vocabulary)) {
    for (const name of entry.names) {
      const button = document.createElement("button");
      const key = keys[`${kind} ${name}`];
      button.innerHTML = (key ? `<kbd>${key}</kbd>` : "") + partLabel(kind, name) +
        (kind === "symmetry" && name !== "roof" ? " (both lights)" : "");
      if (kind === "symmetry") button.title = "a pair: two clicks, the vehicle's left one first (lights: both lamps)";
      palette.appendChild(paletteButton(button, kind, name, clicked));
    }
  }
  // The class's or the mapping's (--mapping) keypoints, those whose name holds every word of the filter.
  const list = $("keypoints");
  list.textContent = "";
  const words = $("keypoint-filter").value.toLowerCase().split(/[\s_]+/).filter(Boolean);
  for (const name of keypoints) {
    if (!words.every((w) => name.toLowerCase().includes(w))) continue;
    const button = document.createElement("button");
    button.textContent = name.replaceAll("_", " ");
    button.title = name;
    list.appendChild(paletteButton(button, "keypoint", name, clicked));
  }
}

function paletteButton(button, kind, name, clicked) {
  button.dataset.kind = kind;
  button.dataset.name = name;
  if (state.armed && state.armed[0] === kind && state.armed[1] === name) button.classList.add("armed");
  if (clicked.has(`${kind} ${name}`)) {
    button.classList.add("clicked");
    button.title = (button.title ? `${button.title}: ` : "") +
      "clicked already; given to another click, the two clicks swap their names";
  }
  button.onclick = () => arm([kind, name]);
  return button;
}

// A name of two clicks (a pair, an arrow) chosen for a click of one: the vocabulary has no single lamp (nor half
// an arrow), so the page says how the pair is clicked; the click keeps waiting for its name.
function pairOnly([kind, name], target) {
  const rest = `Click ${clickNumber(target.index)} still waits for a name of one click (its key), or Delete it.`;
  const key = keyOf(kind, name);
  if (kind === "symmetry") {
    const what = name === "roof" ? "Roof features are" : "Lights are";
    return `${what} clicked as a pair, both lamps: press Esc, then ${key}, and click the vehicle's left one, then its ` +
      `right. ${rest}`;
  }
  return `${partLabel(kind, name)} takes two clicks: press Esc, then ${key}, and click its ` +
    `${CLICK_NAMES[kind].join(", then its ")}. ${rest}`;
}

// How a part's name is chosen: its key, else in the palette.
function keyOf(kind, name) {
  const key = Object.keys(HOTKEYS).find((k) => HOTKEYS[k][0] === kind && HOTKEYS[k][1] === name);
  return key || `${partLabel(kind, name)} in the palette`;
}

// Where left and right matter (a part of one side, or a pair clicked left first): what they mean.
function sides([kind, name]) {
  return /left|right/.test(name) || kind === "symmetry" ?
    ". Left = the vehicle's left, as its driver sees it (on a car facing you, its left is on your right)" : "";
}

// How many clicks an annotation of a kind takes (a keypoint: one).
const clicksOf = (kind) => (kind === "keypoint" ? 1 : state.session.vocabulary[kind].clicks.length);

function arm(choice) {
  const v = currentVehicle();
  const target = v && state.naming !== null ? v.parts[state.naming] : null;
  if (choice && target && clicksOf(choice[0]) === target.uv.length) {  // a name for the click being named
    renameClick(choice[0], choice[1]);
    return;
  }
  if (choice && target && clicksOf(choice[0]) !== target.uv.length) {  // a pair's name for one click: say how
    say(pairOnly(choice, target), true);
    return;
  }
  state.armed = choice;
  state.pending = [];
  if (choice) {
    const first = oneClick(choice[0]) ? "it" : `the ${CLICK_NAMES[choice[0]][0]}`;
    say(`next click: ${partLabel(choice[0], choice[1])} (you chose the name first): click ${first}` + sides(choice));
  } else {
    setNaming(null);
    say("next click: unnamed (you click first; the page names it, or asks)");
  }
  buildPalette();
  render();
}

function fmt(value, digits = 1, scale = 1) {
  return value === null || value === undefined ? "∞" : (value * scale).toFixed(digits);
}

function panels() {
  const list = $("vehicles");
  list.textContent = "";
  for (const v of state.view ? state.view.vehicles : []) {
    const li = document.createElement("li");
    const swatch = `<span class="swatch" style="border-color:${vehicleColour(v)}"></span>`;
    const track = v.track ? ` · ${swatch}${escapeHtml(v.track)}` +
      (v.fit.pose_from ? ` (${v.fit.pose_from})` : "") : "";
    li.innerHTML = `${escapeHtml(v.id)} ${escapeHtml(v.prototype)}${track}: ${clickCount(v)}` + (v.box2d ? ", box" : "") +
      (v.fit.status !== "ok" ? ", not fitted yet" : v.fit.implausible ? ", implausible"
        : v.fit.well_determined ? ", well determined" : ", fitted");
    if (v.id === state.vehicle) li.classList.add("selected");
    if (v.done) li.classList.add("done");
    li.onclick = () => select(v.id);
    list.appendChild(li);
  }
  for (const p of state.view ? state.view.predictions : []) {  // tracks carried to this frame, not on it yet
    const li = document.createElement("li");
    const [before, after] = p.from_frames;
    const held = heldFrom(p);
    const from = held === null ? `between frames ${before} and ${after}` : `held from frame ${held}`;
    li.innerHTML = `<span class="swatch dashed" style="border-color:${trackColour(p.track)}"></span>` +
      `${escapeHtml(p.track)} ${escapeHtml(p.prototype)}: ` +
      (p.fit.status === "ok" ? `predicted, ${from}` : `cannot be predicted: ${escapeHtml(p.fit.error || "")}`);
    li.classList.add("prediction");
    if (p.track === state.prediction) li.classList.add("selected");
    li.onclick = () => select(null, p.track);
    list.appendChild(li);
  }
  for (const track of state.view ? state.view.dismissed : []) {
    const li = document.createElement("li");
    li.textContent = `${track} dismissed on this frame (click: show it again)`;
    li.classList.add("dismissed");
    li.onclick = () => edit({ op: "restore_prediction", track });
    list.appendChild(li);
  }
  const v = currentVehicle();
  banner(v);
  nextClick(v);
  choices(v);
  diagram(v);
  const fit = $("fit");
  const clicks = $("clicks");
  clicks.textContent = "";
  const p = currentPrediction();
  if (p) {
    fit.innerHTML = `<span class="predicted">predicted: track ${escapeHtml(p.track)}</span> ` + predictionHint(p) +
      (p.fit.status === "ok" ? fitTable(p.fit) : `<br>${escapeHtml(p.fit.error || "")}`);
    return;
  }
  if (!v) {
    fit.textContent = "no vehicle: click the image or press n" + (state.view && state.view.predictions.length ?
      "; Tab selects a prediction" : "");
    return;
  }
  $("prototype").value = v.prototype;
  const f = v.fit;
  if (f.status !== "ok") {
    const own = classKeypoints();  // a road user's own keypoints, or null
    const named = v.parts.length - v.unnamed;
    const waiting = v.unnamed ? `${count(v.unnamed, "click")} waiting for a name (choose under Naming)` : "";
    // The fit's "too few clicks" counts points (a pair's two): said here in the page's count, named clicks.
    const few = /^too few clicks: [^;]*; click at least (\d+) more named parts? (\(.*\))$/.exec(f.error || "");
    const why = few ? `${count(named, "named click")} cannot place a cuboid yet; click at least ${few[1]} more ` +
      few[2] : (f.error === "out_of_time" ? f.error_detail : f.error) || "";
    fit.innerHTML = '<span class="bad">not fitted yet</span>: ' + (named ? (waiting ? `${waiting}; with the named ` +
      "ones: " : "") + escapeHtml(why) : (waiting || "no click yet") + (own ?
      `. A fit needs about ${Math.min(5, own.length)} of its ${own.length} keypoints, ` +
      `spread over the ${escapeHtml(v.prototype.toLowerCase())} (choose each under Keypoints).` :
      ". A fit needs about five named clicks: the wheels where they touch the road, the body's vertical edges, " +
      "the front or rear lamps and badge."));
  } else {
    const verdict = f.implausible ? `<span class="bad">implausible</span>: ${escapeHtml(f.implausible)}` +
      (f.likely_cause === "swapped" ? " (left and right look swapped: s swaps them)" : "")
      : f.well_determined ? '<span class="ok">well determined</span>'
      : `<span class="bad">not well determined</span>: ${escapeHtml(f.problems.join("; "))}`;
    const track = v.track ? `<br>track ${escapeHtml(v.track)} (pose: ${f.pose_from}), fitted with frames ` +
      `${f.track_frames[0]} to ${f.track_frames[f.track_frames.length - 1]} (${f.track_frames.length})` : "";
    fit.innerHTML = `${verdict}${track}${fitTable(f)}`;
  }
  v.parts.forEach((p) => {
    const li = document.createElement("li");
    const name = p.name ? `${p.kind === "point" ? "" : p.kind + " "}${p.name}` : "(unnamed: choose its name)";
    const res = p.residuals_px ? Math.max(...p.residuals_px.map(([a, b]) => Math.hypot(a, b))).toFixed(1) + " px" : "";
    const by = p.auto ? `<span class="auto" title="named by the page from ${p.auto.how === "prior" ?
      "the prior cuboid" : "the fit"}">auto</span>` : "";
    li.innerHTML = `${escapeHtml(name)} ${by} <span class="res">${res}</span>`;
    {
      const rename = document.createElement("button");
      rename.className = "rename";
      rename.textContent = "rename";
      rename.title = "rename this click (r): then press a part's key or choose a name";
      rename.onclick = (e) => { e.stopPropagation(); startRename(p.index); };
      li.appendChild(rename);
    }
    if (p.index === state.selectedPart) li.classList.add("selected");
    if (p.index === state.naming) li.classList.add("naming");
    li.onclick = () => {  // what the message said was about another click: it now says which one is selected
      state.selectedPart = p.index;
      say(`click ${clickNumber(p.index)} selected: r renames it, Delete removes it, drag it on the image to move it`);
      render();
    };
    clicks.appendChild(li);
  });
}

// The banner over the image: the selected vehicle's fit is one no person could have clicked, with the likely cause
// and the fix.
function banner(v) {
  const el = $("banner");
  const f = v && v.fit;
  if (!f || f.status !== "ok" || !f.implausible) { el.hidden = true; return; }
  el.hidden = false;
  if (f.likely_cause === "swapped") {
    el.innerHTML = "<b>Left and right look swapped.</b> Left = the vehicle's own left, as its driver sees it (seen " +
      "from the front, its left is on the image's right). " +
      '<button id="swap-now">Swap left and right</button> (or press <kbd>s</kbd>), or rename the clicks.';
    $("swap-now").onclick = swapSides;
  } else if (f.likely_cause === "axles") {
    el.innerHTML = `<b>The wheels look named on the wrong axles</b> (${escapeHtml(f.implausible)}). Front = the ` +
      "vehicle's own front, where its headlights are; rear, where its tail lights are. Rename the wheel clicks " +
      "(select one, press r) so each is named for the axle it is on, and click each where its tyre touches the road.";
  } else {
    el.innerHTML = `<b>No one could have clicked this fit</b> (${escapeHtml(f.implausible)}): check the clicks' ` +
      "names (front and rear, left and right: the vehicle's own, as its driver sees them) and that they are all " +
      "on this vehicle; rename a click with r.";
  }
}

// What the next click will be: a name chosen first, a click being named, or unnamed (the page names it or asks).
function nextClick(v) {
  const el = $("next-click");
  if (state.naming !== null && v && v.parts[state.naming]) {
    el.textContent = (state.renaming ? `Renaming click ${clickNumber(state.naming)}` :
      `Naming click ${clickNumber(state.naming)}`) + `: ${howToName()}. ` +
      (state.renaming ? "Esc: keep its name." : "Esc: name the next click instead.");
    el.className = "naming";
  } else if (state.armed) {
    el.textContent = `Next click: ${partLabel(state.armed[0], state.armed[1])} (you chose the name first). Esc: ` +
      "click first instead.";
    el.className = "armed";
  } else {
    el.textContent = classKeypoints() ? "Next click: choose its keypoint under Keypoints first, then click it; or " +
      "click first, and the page names it once the clicks fit (else it asks you)." :
      "Next click: click first, the page names it from where it is (or asks you). Or press a part's key first " +
      "to name it yourself.";
    el.className = "";
  }
}

// The names the page offers for the click being named, or instead of the name it gave the selected click.
function choices(v) {
  const el = $("choices");
  el.textContent = "";
  const k = state.naming !== null ? state.naming : state.selectedPart;
  const part = v && k !== null ? v.parts[k] : null;
  if (!part || (part.name && !part.auto)) return;
  // The names worth offering: those the page gives at least 1 % (all when it ranks by distance).
  const offered = (part.choices || []).filter((c) => c.probability === undefined || c.probability === null ||
    c.probability >= 0.01);
  const head = document.createElement("span");
  head.textContent = part.name ? `Click ${clickNumber(k)} is ${part.name} (the page's name)` +
    (offered.length ? "; or: " : "; r renames it") :
    `Click ${clickNumber(k)} may be` + (offered.length && offered[0].far ?
      " (far from every part of the fitted vehicle; the nearest, by the naming model's odds): " : ": ") +
    (offered.length ? "" : classKeypoints() ? "any of its keypoints (under Keypoints)" : "any name of the palette");
  el.appendChild(head);
  for (const c of offered) {
    const button = document.createElement("button");
    const sure = c.probability !== undefined && c.probability !== null ? ` ${Math.round(100 * c.probability)} %` : "";
    button.textContent = `${c.name}${sure}`;
    button.dataset.name = c.name;
    button.onclick = () => { setNaming(k, Boolean(part.name)); renameClick(c.kind, c.name); };
    el.appendChild(button);
  }
}

// The parts diagram: the parts the selected vehicle has clicked, marked.
function diagram(v) {
  const clicked = new Set(v ? v.parts.filter((p) => p.name).map((p) => p.name) : []);
  for (const el of document.querySelectorAll("#diagram [data-part]")) {
    el.classList.toggle("clicked", clicked.has(el.dataset.part));
  }
}

function fitTable(f) {
  const sigma = f.sigma || {};
  return `<table>
      <tr><td>yaw</td><td>${f.yaw_pitch_roll_deg[0].toFixed(1)}°</td><td>σ ${fmt(sigma.yaw_deg)}°</td></tr>
      <tr><td>depth</td><td>${f.depth_m.toFixed(2)} m</td><td>σ ${fmt(sigma.depth_rel, 1, 100)} %</td></tr>
      <tr><td>size</td><td colspan="2">${f.dimensions.map((d) => d.toFixed(2)).join(" × ")} m</td></tr>
      ${f.rms_px === null || f.rms_px === undefined ? "" :  // no clicks on a track's frame: no rms
    `<tr><td>rms</td><td colspan="2">${fmt(f.rms_px, 2)} px</td></tr>`}
      <tr><td>for</td><td colspan="2">clicks σ ${fmt(f.click_sigma_px, 2)} px${f.road ? `, upright on the road (${f.road})` : ""}</td></tr></table>`;
}

function escapeHtml(text) {
  return String(text).replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" }[c]));
}

// -- drawing ---------------------------------------------------------------------------------------------------

// The whole image, as large as the canvas holds it: a wide image (KITTI's 1242 x 375) fills the canvas's width. It
// stays so (state.fitted) when the canvas changes size, until the person zooms or pans; 0 fits it again. Clicks
// stay in image pixels whatever the zoom (toImage).
function fitToView() {
  const rect = canvas.getBoundingClientRect();
  const [w, h] = state.session.images[state.index].size;
  state.zoom = Math.min(rect.width / w, rect.height / h);
  state.panX = (rect.width - w * state.zoom) / 2;
  state.panY = (rect.height - h * state.zoom) / 2;
  state.fitted = true;
  render();
}

// The canvas changed size (the window, the side panel): the image fitted again unless the person zoomed or panned.
function resized() {
  if (state.fitted && state.session) fitToView();
  else render();
}

const toScreen = ([u, v]) => [u * state.zoom + state.panX, v * state.zoom + state.panY];
const toImage = (x, y) => [(x - state.panX) / state.zoom, (y - state.panY) / state.zoom];
// Whether an image pixel lies on the image shown (not on the grey around it): only such clicks are sent.
function onImage([u, v]) {
  const [w, h] = state.session.images[state.index].size;
  return u >= 0 && v >= 0 && u <= w && v <= h;
}
const clampToImage = ([u, v]) => {
  const [w, h] = state.session.images[state.index].size;
  return [Math.min(Math.max(u, 0), w), Math.min(Math.max(v, 0), h)];
};
const OFF_IMAGE = "that is outside the image: click on the image itself (zoom out with the wheel or 0 to see all of it)";

function line(a, b, colour, width = 1.5, dash = []) {
  ctx.strokeStyle = colour;
  ctx.lineWidth = width;
  ctx.setLineDash(dash);
  ctx.beginPath();
  ctx.moveTo(...toScreen(a));
  ctx.lineTo(...toScreen(b));
  ctx.stroke();
  ctx.setLineDash([]);
}

function dot(p, colour, radius = 4, outline = "#000") {
  const [x, y] = toScreen(p);
  ctx.fillStyle = colour;
  ctx.strokeStyle = outline;
  ctx.lineWidth = 1;
  ctx.beginPath();
  ctx.arc(x, y, radius, 0, 2 * Math.PI);
  ctx.fill();
  ctx.stroke();
}

// Boxes [x, y, w, h] taken this frame: the labels drawn (`placedLabels`), and the selected vehicle's click dots and
// target circles (`markBoxes`, obstacles, each with its centre). A label goes beside its point (above
// right, below right, above left, below left) where it overlaps nothing taken and no other mark is nearer to it than
// its own; else farther out, away from the vehicle's middle, joined to its point by a thin line that crosses no other
// label (nor, where it can, a mark); where nothing is free it is left out (zoom in to see it), unless it is the
// selected click's.
let placedLabels = [];
let markBoxes = [];  // [x, y, w, h, centre x, centre y]: overlapping() reads the box, the rest the centre
const overlapping = (a, b) => a[0] < b[0] + b[2] && b[0] < a[0] + a[2] && a[1] < b[1] + b[3] && b[1] < a[1] + a[3];
const LABEL_HEIGHT = 15;
const LEADER_RINGS = [22, 36, 54, 78, 110, 150, 200];  // screen pixels from the point to a far label's nearest side
const LEADER_DIRECTIONS = 16;

function obstacle(p, radius) {
  const [x, y] = toScreen(p);
  markBoxes.push([x - radius, y - radius, 2 * radius, 2 * radius, x, y]);
}

// Screen distance from (x, y) to box b, 0 inside it.
function boxDistance(b, x, y) {
  return Math.hypot(Math.max(b[0] - x, 0, x - b[0] - b[2]), Math.max(b[1] - y, 0, y - b[1] - b[3]));
}

// The point of box b nearest to (x, y).
const nearestOnBox = (b, x, y) => [Math.min(Math.max(x, b[0]), b[0] + b[2]), Math.min(Math.max(y, b[1]), b[1] + b[3])];

// Whether the segment from a to c crosses box b (Liang-Barsky clipping).
function segmentCrosses(a, c, b) {
  let t0 = 0;
  let t1 = 1;
  const d = [c[0] - a[0], c[1] - a[1]];
  for (const [p, q] of [[-d[0], a[0] - b[0]], [d[0], b[0] + b[2] - a[0]], [-d[1], a[1] - b[1]],
    [d[1], b[1] + b[3] - a[1]]]) {
    if (p === 0) {
      if (q < 0) return false;
    } else if (p < 0) {
      t0 = Math.max(t0, q / p);
    } else {
      t1 = Math.min(t1, q / p);
    }
    if (t0 > t1) return false;
  }
  return true;
}

// Far places for a label w wide around (x, y): ring by ring, the directions nearest to `away` (a unit vector, or
// null) first; each box's side nearest to the point is the ring's distance from it.
function farPlaces(x, y, w, away) {
  const places = [];
  for (const r of LEADER_RINGS) {
    const ring = [];
    for (let k = 0; k < LEADER_DIRECTIONS; k++) {
      const a = (2 * Math.PI * k) / LEADER_DIRECTIONS;
      const [c, s] = [Math.cos(a), Math.sin(a)];
      const [ax, ay] = [x + r * c, y + r * s];
      const bx = c > 0.38 ? ax : c < -0.38 ? ax - w : ax - w / 2;
      const by = s > 0.38 ? ay : s < -0.38 ? ay - LABEL_HEIGHT : ay - LABEL_HEIGHT / 2;
      ring.push({ box: [bx, by, w, LABEL_HEIGHT], score: away ? -(c * away[0] + s * away[1]) : k });
    }
    ring.sort((a, b) => a.score - b.score);
    places.push(...ring.map((place) => place.box));
  }
  return places;
}

// `options.always`: drawn even where nothing is free (the selected click's); `options.gap`: screen pixels between
// the point and a label beside it (beyond the point's own dot or circle); `options.own`: screen points that are the
// label's own besides `p` (a pair's other click); `options.middle`: the screen point far labels go away from.
function label(p, text, colour, options = {}) {
  const { always = false, gap = 7, own = [], middle = null } = options;
  const [x, y] = toScreen(p);
  ctx.font = "12px system-ui, sans-serif";
  const w = ctx.measureText(text).width;
  const free = (b) => !placedLabels.some((taken) => overlapping(b, taken)) &&
    !markBoxes.some((taken) => overlapping(b, taken));
  const mine = [[x, y], ...own];
  const isMine = (mx, my) => mine.some(([ox, oy]) => Math.abs(mx - ox) < 0.5 && Math.abs(my - oy) < 0.5);
  const nearestIsOwn = (b) => {
    const distance = boxDistance(b, x, y);
    return markBoxes.every((m) => isMine(m[4], m[5]) || boxDistance(b, m[4], m[5]) > distance);
  };
  const beside = [[x + gap, y - 19], [x + gap, y + 5], [x - gap - w, y - 19], [x - gap - w, y + 5]].map(
    ([bx, by]) => [bx, by, w, LABEL_HEIGHT]);
  let box = beside.find((b) => free(b) && nearestIsOwn(b));
  let leader = null;
  if (!box) {
    const rect = canvas.getBoundingClientRect();
    const onScreen = (b) => b[0] >= 0 && b[1] >= 0 && b[0] + b[2] <= rect.width && b[1] + b[3] <= rect.height;
    const length = middle ? Math.hypot(x - middle[0], y - middle[1]) : 0;
    const away = length > 1 ? [(x - middle[0]) / length, (y - middle[1]) / length] : null;
    // A line crossing no other label or mark if there is one, else one crossing marks only (a dense cluster's
    // middle dot has marks all round); never one across another label.
    const crosses = (end, boxes) => boxes.some((taken) => !overlapping(taken, [x - 6, y - 6, 12, 12]) &&
      segmentCrosses([x, y], end, taken));  // its own dot aside
    let acrossMarks = null;
    for (const b of farPlaces(x, y, w, away)) {
      if (!onScreen(b) || !free(b)) continue;
      const end = nearestOnBox(b, x, y);
      if (crosses(end, placedLabels)) continue;
      if (!crosses(end, markBoxes)) {
        box = b;
        leader = end;
        break;
      }
      acrossMarks = acrossMarks || [b, end];
    }
    if (!box && acrossMarks) [box, leader] = acrossMarks;
  }
  if (!box && !always) return;
  box = box || beside[0];
  placedLabels.push(box);
  state.labels.push({ text, box, point: [x, y], leader });
  if (leader) {
    const d = Math.hypot(leader[0] - x, leader[1] - y);
    ctx.strokeStyle = colour;
    ctx.lineWidth = 1;
    ctx.beginPath();
    ctx.moveTo(x + ((leader[0] - x) * 5) / d, y + ((leader[1] - y) * 5) / d);  // from the dot's rim
    ctx.lineTo(...leader);
    ctx.stroke();
  }
  ctx.lineWidth = 3;
  ctx.strokeStyle = "rgba(0,0,0,0.7)";
  ctx.strokeText(text, box[0], box[1] + 12);
  ctx.fillStyle = colour;
  ctx.fillText(text, box[0], box[1] + 12);
}

const EDGES = [[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4], [0, 4], [1, 5], [2, 6], [3, 7]];

function render() {
  const rect = canvas.getBoundingClientRect();
  const dpr = window.devicePixelRatio || 1;  // drawn at the screen's pixels, in CSS pixels: sharp lines and labels
  if (canvas.width !== Math.round(rect.width * dpr) || canvas.height !== Math.round(rect.height * dpr)) {
    canvas.width = Math.round(rect.width * dpr);
    canvas.height = Math.round(rect.height * dpr);
  }
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.clearRect(0, 0, rect.width, rect.height);
  placedLabels = [];
  markBoxes = [];
  state.labels = [];
  if (state.image.complete && state.image.naturalWidth) {
    ctx.imageSmoothingEnabled = state.zoom < 2;
    ctx.drawImage(state.image, state.panX, state.panY, state.image.naturalWidth * state.zoom,
      state.image.naturalHeight * state.zoom);
  }
  state.drawn = [];  // what this frame shows, for tests: {track, vehicle, style: "solid" | "dashed"}
  if (state.view) {
    for (const p of state.view.predictions) drawPrediction(p, p.track === state.prediction);
    for (const v of state.view.vehicles) drawVehicle(v, v.id === state.vehicle);
  }
  for (const p of state.pending) dot(p, "#ffd479", 4);
  if (state.drag && state.drag.kind === "box") {
    const [x0, y0] = toScreen(state.drag.from);
    const [x1, y1] = toScreen(state.drag.to);
    ctx.strokeStyle = "#ffd479";
    ctx.setLineDash([4, 3]);
    ctx.strokeRect(x0, y0, x1 - x0, y1 - y0);
    ctx.setLineDash([]);
  }
  panels();
}

function drawVehicle(v, selected) {
  const f = v.fit;
  const alpha = selected ? 1 : 0.45;
  ctx.globalAlpha = alpha;
  if (v.box2d) {
    const [x0, y0] = toScreen([v.box2d[0], v.box2d[1]]);
    const [x1, y1] = toScreen([v.box2d[2], v.box2d[3]]);
    ctx.strokeStyle = "#9ecbff";
    ctx.lineWidth = 1;
    ctx.strokeRect(x0, y0, x1 - x0, y1 - y0);
  }
  if (f.status === "ok" && f.corners_uv) {
    const c = f.corners_uv;
    drawCuboid(f, "rgba(255, 80, 80, 0.25)", "#ff5050", vehicleColour(v), (front) => (front ? 2.5 : 1.5), []);
    state.drawn.push({ track: v.track, vehicle: v.id, style: "solid" });
    if (v.track) {
      label(topCorner(c), `${v.track}` + (f.pose_from ? ` (${f.pose_from})` : ""), vehicleColour(v),
        { always: selected });
    }
  }
  if (selected) {
    v.targets.forEach((t, k) => {
      if (t.uv.length === 2) line(t.uv[0], t.uv[1], "#ffd479", 1.5, [6, 4]);  // a pair or an arrow, tail to head
      t.uv.forEach((p) => {
        const [x, y] = toScreen(p);
        ctx.strokeStyle = "#ffd479";
        ctx.lineWidth = 1.5;
        ctx.setLineDash([3, 3]);
        ctx.beginPath();
        ctx.arc(x, y, 9, 0, 2 * Math.PI);
        ctx.stroke();
        ctx.setLineDash([]);
      });
    });
  }
  for (const p of v.parts) {
    p.uv.forEach((uv, k) => {
      if (p.residuals_px) {  // residual: projected minus clicked, drawn 5 times longer
        const r = p.residuals_px[k];
        line(uv, [uv[0] + 5 * r[0], uv[1] + 5 * r[1]], "#ff00ff", 1.5);
      }
      const colour = !p.name ? "#ff9800" : p.auto ? "#ffeb3b" : "#4caf50";
      dot(uv, colour, p.index === state.selectedPart && selected ? 6 : 4, selected ? "#000" : "#444");
    });
  }
  if (selected) {  // labels last, around what is drawn: the clicks' names first, then the targets'
    for (const p of v.parts) p.uv.forEach((uv) => obstacle(uv, 5));
    for (const t of v.targets) t.uv.forEach((uv) => obstacle(uv, 9));
    const marks = [...v.parts.flatMap((p) => p.uv), ...v.targets.flatMap((t) => t.uv)].map(toScreen);
    const middle = [marks.reduce((sum, m) => sum + m[0], 0) / marks.length,
      marks.reduce((sum, m) => sum + m[1], 0) / marks.length];
    const order = [...v.parts].sort((a, b) => (b.index === state.selectedPart) - (a.index === state.selectedPart));
    for (const p of order) {
      const text = p.name ? (oneClick(p.kind) ? p.name : `${p.name} ${p.kind}`) : "?";
      label(p.uv[0], text, p.name ? "#fff" : "#ff9800",
        { always: p.index === state.selectedPart, own: p.uv.slice(1).map(toScreen), middle });
    }
    // Targets are ranked with circled numbers, so that they are not read as click numbers (click 1, click 2, ...).
    v.targets.forEach((t, k) => label(t.uv[0], `${TARGET_RANKS[k] ?? k + 1} ${t.name}`, "#ffd479",
      { gap: 11, own: t.uv.slice(1).map(toScreen), middle }));
  }
  ctx.globalAlpha = 1;
}

// The targets' ranks as drawn beside them, best first.
const TARGET_RANKS = ["①", "②", "③", "④", "⑤", "⑥", "⑦", "⑧", "⑨"];

// The corner drawn highest on the screen: where a cuboid's track label goes.
function topCorner(c) {
  return c.reduce((best, p) => (p[1] < best[1] ? p : best), c[0]);
}

// A track carried to this frame: its predicted cuboid, dashed, in the track's colour (thicker when selected).
// A fit's cuboid: its front face filled with `fill`, its front edges in `frontColour` and the others in `colour`,
// each as wide as `width(isFront)`, dashed by `dash` ([] for solid).
function drawCuboid(f, fill, frontColour, colour, width, dash) {
  const c = f.corners_uv;
  ctx.fillStyle = fill;
  ctx.beginPath();
  f.front_face.forEach((i, k) => (k ? ctx.lineTo(...toScreen(c[i])) : ctx.moveTo(...toScreen(c[i]))));
  ctx.closePath();
  ctx.fill();
  for (const [i, j] of EDGES) {
    const front = f.front_face.includes(i) && f.front_face.includes(j);
    line(c[i], c[j], front ? frontColour : colour, width(front), dash);
  }
}

function heldFrom(p) {
  // The placed frame a prediction stands where it stood (no frame on either side to interpolate between), or null.
  const [before, after] = p.from_frames;
  return p.source === "interpolated" ? null : (before !== null ? before : after);
}

function predictionHint(p) {
  // What the keys do on a prediction. One held from a single side has no motion to follow: it stands where the
  // track was placed, which is wrong for a vehicle that moved since, so the box comes first there.
  const held = heldFrom(p);
  return held === null ? "(Enter confirms it, b draws its box, a click starts its parts, x dismisses it on this frame)"
    : `(held where frame ${held} placed it: if it has moved since, b draws its box or a click starts its parts; ` +
      "Enter confirms it as drawn, x dismisses it on this frame)";
}

function drawPrediction(p, selected) {
  const f = p.fit;
  if (f.status !== "ok" || !f.corners_uv) return;
  const c = f.corners_uv;
  const colour = trackColour(p.track);
  ctx.globalAlpha = selected ? 1 : 0.75;
  drawCuboid(f, selected ? "rgba(255, 80, 80, 0.12)" : "rgba(255, 80, 80, 0.06)", "#ff8a80", colour,
    () => (selected ? 2.5 : 1.5), [7, 5]);
  const keys = heldFrom(p) === null ? ": Enter confirms, x dismisses" : ": b boxes it if it moved, Enter confirms";
  label(topCorner(c), `${p.track} predicted` + (selected ? keys : ""), colour, { always: selected });
  ctx.globalAlpha = 1;
  state.drawn.push({ track: p.track, vehicle: null, style: "dashed" });
}

// -- mouse and keys ------------------------------------------------------------------------------------------

function nearestClick(x, y) {
  const v = currentVehicle();
  if (!v) return null;
  let best = null;
  for (const p of v.parts) {
    p.uv.forEach((uv, k) => {
      const [sx, sy] = toScreen(uv);
      const d = Math.hypot(sx - x, sy - y);
      if (d <= 7 && (!best || d < best.d)) best = { part: p.index, click: k, d };
    });
  }
  return best;
}

canvas.addEventListener("contextmenu", (e) => e.preventDefault());
canvas.addEventListener("mousedown", (e) => {
  const x = e.offsetX, y = e.offsetY;
  if (e.button === 2 || e.shiftKey) {
    state.drag = { kind: "pan", x, y, panX: state.panX, panY: state.panY };
  } else if (state.mode === "box") {
    state.drag = { kind: "box", from: toImage(x, y), to: toImage(x, y) };
  } else {
    const hit = nearestClick(x, y);
    state.drag = hit ? { kind: "move", ...hit, x, y, moved: false } : { kind: "click", x, y };
  }
});
canvas.addEventListener("mousemove", (e) => {
  const d = state.drag;
  if (!d) return;
  if (d.kind === "pan") {
    state.panX = d.panX + e.offsetX - d.x;
    state.fitted = false;
    state.panY = d.panY + e.offsetY - d.y;
    render();
  } else if (d.kind === "box") {
    d.to = toImage(e.offsetX, e.offsetY);
    render();
  } else if (d.kind === "move" && Math.hypot(e.offsetX - d.x, e.offsetY - d.y) > 2) {
    d.moved = true;
    const v = currentVehicle();
    v.parts[d.part].uv[d.click] = toImage(e.offsetX, e.offsetY);
    render();
  }
});
canvas.addEventListener("mouseup", async (e) => {
  const d = state.drag;
  state.drag = null;
  if (!d) return;
  if (d.kind === "box") {
    state.mode = "click";
    const [u0, v0] = clampToImage(d.from), [u1, v1] = clampToImage(toImage(e.offsetX, e.offsetY));
    const box = [Math.min(u0, u1), Math.min(v0, v1), Math.max(u0, u1), Math.max(v0, v1)];
    if (box[2] - box[0] < 2 || box[3] - box[1] < 2) { say("box too small", true); render(); return; }
    if (state.prediction !== null) {  // the prediction's box: its track gets a vehicle with that box only
      const track = state.prediction;
      await newVehicle(box, track);
      say(`track ${track}: box drawn on this frame (its pose from the box and the track)`);
    } else {
      const doc = currentVehicle() && !currentVehicle().parts.length && !currentVehicle().box2d ?
        await edit({ op: "set_vehicle", vehicle: state.vehicle, box2d: box }) : await newVehicle(box);
      if (doc) say(`box drawn for vehicle ${state.vehicle}: the page places its prototype's cuboid in it and ` +
                   "can name your clicks from the first one");
    }
  } else if (d.kind === "move") {
    state.selectedPart = d.part;
    const uv = toImage(e.offsetX, e.offsetY);
    if (d.moved && !onImage(uv)) {
      await loadView();  // the click back where it was
      say(OFF_IMAGE, true);
    } else if (d.moved) {
      await edit({ op: "move_click", vehicle: state.vehicle, part: d.part, click: d.click, uv });
    } else if (state.armed || state.pending.length) {  // a name chosen first: this press is the click it names
      await addClick(uv);
    } else {
      say(`click ${clickNumber(d.part)} selected: drag it to move it; to click beside it, zoom in (mouse wheel)`);
      render();
    }
  } else if (d.kind === "click") {
    const uv = toImage(e.offsetX, e.offsetY);
    if (onImage(uv)) await addClick(uv);
    else say(OFF_IMAGE, true);
  }
});
canvas.addEventListener("wheel", (e) => {
  e.preventDefault();
  const factor = Math.exp(-e.deltaY * 0.0015);
  const [u, v] = toImage(e.offsetX, e.offsetY);
  state.zoom = Math.min(Math.max(state.zoom * factor, 0.05), 40);
  state.fitted = false;
  state.panX = e.offsetX - u * state.zoom;
  state.panY = e.offsetY - v * state.zoom;
  render();
}, { passive: false });

document.addEventListener("keydown", async (e) => {
  if (e.target.tagName === "SELECT" || e.target.tagName === "INPUT") return;
  const key = e.key;
  if (key === "Enter" && e.target.tagName === "BUTTON") return;  // the focused button's own click, not a confirm too
  if ((e.ctrlKey || e.metaKey) && key === "z") { e.preventDefault(); await undo(); return; }
  if (e.ctrlKey || e.metaKey || e.altKey) return;
  if (HOTKEYS[key] && classKeypoints()) {  // a pedestrian has no wheel: its parts are its keypoints
    say(`a ${palettePrototype()} is clicked on its keypoints: choose one under Keypoints`, true);
  } else if (HOTKEYS[key]) arm(HOTKEYS[key]);
  else if (key === "Escape") { state.mode = "click"; setNaming(null); arm(null); }
  else if (key === "s") await swapSides();
  else if (key === "r") startRename(state.selectedPart);
  else if (key === "u") await undo();
  else if (key === "Enter" && state.prediction !== null) await confirmPrediction();
  else if (key === "Tab") { e.preventDefault(); cycleSelection(e.shiftKey ? -1 : 1); }
  else if ((key === "x" || key === "Delete" || key === "Backspace") && state.prediction !== null) {
    await dismissPrediction();
  } else if (key === "x") await takeRunnerUp();
  else if (key === "n") await newVehicle();
  else if (key === "b") {
    state.mode = "box";
    say(state.prediction !== null ? `drag the box of track ${state.prediction}` : "drag the vehicle's box");
  } else if (key === "d") await toggleDone();
  else if (key === "]" || key === "PageDown") await step(1);
  else if (key === "[" || key === "PageUp") await step(-1);
  else if (key === "0") fitToView();
  else if ((key === "Delete" || key === "Backspace") && state.selectedPart !== null && currentVehicle()) {
    await deleteClick();
  }
});

async function toggleDone() {
  const v = currentVehicle();
  if (v && await edit({ op: "set_vehicle", vehicle: v.id, done: !v.done })) {
    say(`vehicle ${v.id} marked ${v.done ? "not done" : "done"}`);
  }
}

// Read the annotation file and its extras file again (after another program changed them); this page's undo
// history is dropped.
async function reloadFiles() {
  const { status, doc } = await api("POST", "/api/reload", {});
  if (status !== 200) { say(doc.error, true); return; }
  $("reload").hidden = true;
  state.session = doc;
  state.revision = doc.revision;
  await loadView();
  say("reloaded from the files as they are now");
}

$("reload").onclick = reloadFiles;
$("prev").onclick = () => step(-1);
$("next").onclick = () => step(1);
$("confirm").onclick = confirmPrediction;
$("dismiss").onclick = dismissPrediction;
$("new-vehicle").onclick = () => newVehicle();
$("draw-box").onclick = () => { state.mode = "box"; say("drag the vehicle's box"); };
$("done").onclick = toggleDone;
$("undo").onclick = undo;
$("prototype").onchange = async () => {
  const v = currentVehicle();
  if (v) await edit({ op: "set_vehicle", vehicle: v.id, prototype: $("prototype").value });
  buildPalette();  // a pedestrian's keypoints, or the cuboid parts
};
window.addEventListener("resize", resized);
new ResizeObserver(resized).observe($("view"));
start();
