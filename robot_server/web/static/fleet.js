// robot-server fleet index: every controller of the fleet, its state at a glance, each linking to
// its own page (c/NAME/). Reads fleet.json every `period` seconds the server gives; docs/web.md.

const fleetview = {
  connected: false,
  polls: 0,
  data: null,
};
window.fleetview = fleetview;

const $ = (sel) => document.querySelector(sel);
// the web view's token, from this page's address: the controllers' links carry it on
const TOKEN = new URLSearchParams(location.search).get('token');
const QUERY = TOKEN ? `?token=${encodeURIComponent(TOKEN)}` : '';
const LIGHTS = [
  ['drives_powered', 'drives'],
  ['e_stopped', 'e-stop'],
  ['in_error', 'error'],
];

function setConnection(state) {
  const el = $('#connection');
  el.dataset.state = state;
  el.textContent = state === 'open' ? 'connected' : state === 'closed' ? 'disconnected' : 'connecting';
  fleetview.connected = state === 'open';
}

function cell(tr, cls) {
  const td = document.createElement('td');
  td.className = cls;
  tr.appendChild(td);
  return td;
}

function light(td, name, label) {
  const span = document.createElement('span');
  span.className = 'light';
  span.dataset.light = name;
  span.dataset.state = 'unknown';
  span.textContent = label;
  td.appendChild(span);
  return span;
}

const rows = new Map(); // name -> {tr, parts}

function makeRow(c) {
  const tr = document.createElement('tr');
  tr.dataset.name = c.name;
  const parts = {};
  const a = document.createElement('a');
  a.href = `${c.url}${QUERY}`;
  a.textContent = c.name;
  cell(tr, 'name').appendChild(a);
  parts.profile = cell(tr, 'profile');
  parts.models = cell(tr, 'models');
  parts.ports = cell(tr, 'ports');
  for (const [name, label] of LIGHTS) parts[name] = light(cell(tr, name), name, label);
  parts.code = document.createElement('span');
  parts.code.className = 'error-code';
  parts.in_error.parentNode.appendChild(parts.code);
  parts.mode = cell(tr, 'mode');
  parts.in_motion = light(cell(tr, 'in_motion'), 'in_motion', 'motion');
  parts.clients = cell(tr, 'clients');
  return { tr, parts };
}

function text(el, value) {
  if (el.textContent !== value) el.textContent = value;
}

function showRow(row, c) {
  const p = row.parts;
  const s = c.status || {};
  text(p.profile, String(c.profile ?? ''));
  text(p.models, (c.models || []).join(' + '));
  const ports = Object.entries(c.ports || {}).map(([role, port]) => `${role} :${port}`);
  if (c.serial) ports.push(`serial ${c.serial}`);
  text(p.ports, ports.join(', '));
  p.ports.title = c.host ? `on ${c.host}` : '';
  for (const name of ['drives_powered', 'e_stopped', 'in_error', 'in_motion']) {
    const v = s[name];
    p[name].dataset.state = v === true ? 'on' : v === false ? 'off' : 'unknown';
  }
  text(p.code, s.in_error && Number(s.error_code) ? String(s.error_code) : '');
  text(p.mode, s.mode != null ? String(s.mode) : '–');
  p.mode.dataset.mode = String(s.mode || '').toLowerCase();
  const clients = c.clients || {};
  const total = Object.values(clients).reduce((n, k) => n + Number(k || 0), 0);
  text(p.clients, String(total));
  p.clients.title = Object.entries(clients).map(([role, n]) => `${role}: ${n}`).join(', ');
  row.tr.dataset.alarm = s.e_stopped || s.in_error ? 'true' : 'false';
}

function showFleet(data) {
  const list = Array.isArray(data.controllers) ? data.controllers : [];
  const tbody = $('#fleet tbody');
  const seen = new Set();
  list.forEach((c, i) => {
    if (!c || typeof c.name !== 'string') return;
    seen.add(c.name);
    let row = rows.get(c.name);
    if (!row) {
      row = makeRow(c);
      rows.set(c.name, row);
    }
    if (tbody.children[i] !== row.tr) tbody.insertBefore(row.tr, tbody.children[i] || null);
    showRow(row, c);
  });
  for (const [name, row] of rows) {
    if (!seen.has(name)) {
      row.tr.remove();
      rows.delete(name);
    }
  }
  const count = (pred) => list.filter((c) => pred(c.status || {})).length;
  const parts = [`${list.length} controller${list.length === 1 ? '' : 's'}`];
  const stopped = count((s) => s.e_stopped);
  const errors = count((s) => s.in_error);
  const moving = count((s) => s.in_motion);
  if (stopped) parts.push(`${stopped} e-stopped`);
  if (errors) parts.push(`${errors} in error`);
  if (moving) parts.push(`${moving} moving`);
  text($('#fleet-summary'), parts.join(' · '));
  const control = data.control || {};
  const note = $('#read-only');
  note.hidden = control.commands !== false;
  text(note, control.commands === false ? String(control.why || 'read-only') : '');
  note.title = note.textContent;
}

let period = 1.0;

async function poll() {
  try {
    const response = await fetch(`fleet.json${QUERY}`, { cache: 'no-store' });
    if (!response.ok) throw new Error(`HTTP ${response.status}`);
    const data = await response.json();
    if (typeof data.period === 'number' && data.period > 0) period = data.period;
    fleetview.data = data;
    fleetview.polls += 1;
    showFleet(data);
    setConnection('open');
  } catch (err) {
    setConnection('closed');
  }
  setTimeout(poll, period * 1000);
}

poll();
