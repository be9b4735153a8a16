// tmcl-sim dashboard: one page for the whole server, fed over a WebSocket (docs/dashboard.md).
// The server sends "hello" once and then a "frame" each time this page has drawn the last one
// and acknowledged it ({"op": "ack"}); everything the page does goes back as a small message.
"use strict";

(() => {
  const $ = (id) => document.getElementById(id);

  function el(tag, attributes = {}, ...children) {
    const node = document.createElement(tag);
    for (const [key, value] of Object.entries(attributes)) {
      if (key === "class") node.className = value;
      else if (key === "text") node.textContent = value;
      else if (key.startsWith("on")) node.addEventListener(key.slice(2), value);
      else node.setAttribute(key, value);
    }
    for (const child of children) node.append(child);
    return node;
  }

  /** Write text only when it changed: every write makes the browser lay out and paint again. */
  function setText(node, text) {
    const value = String(text);
    if (node.textContent !== value) node.textContent = value;
  }

  function setValue(input, value) {
    const text = String(value);
    if (document.activeElement !== input && input.value !== text) input.value = text;
  }

  const KEEP_S = 120;          // samples kept (simulated seconds), as on the server
  const WIRE_KEEP = 1000;      // wire lines kept
  // The live wire view shows the newest rows twice a second (painting a table of text at
  // frame rate cost a browser more CPU than the rest of the page); paused, it shows every
  // kept line that matches, to scroll through.
  const WIRE_LIVE_ROWS = 18, WIRE_PAUSED_ROWS = 1000, WIRE_REFRESH_MS = 500;
  const POSITION = "#1f6feb", TARGET = "#6ea8fe", VELOCITY = "#e8710a", LIMIT = "#f0a868";

  const state = {
    hello: null,
    description: null,        // the module shown
    slot: null,
    frame: null,
    frames: 0,
    windowS: 10,
    samples: null,            // {t: [], position: [[]], velocity: [[]], target: [[]]}
    plots: [],
    listing: [],              // [[address, label, text]]
    wire: [],                 // [[sim, wall, endpoint, module, kind, text]]
    endpoints: new Set(),
    wireSkipped: 0,           // telegrams the server counted but did not send (a flood)
    wireDirty: false,
    wireShownAt: 0,
    replies: new Map(),
    nextId: 1,
    socket: null,
    drawPending: false,
  };

  // -- connection ------------------------------------------------------------------------------

  function connect() {
    const scheme = location.protocol === "https:" ? "wss" : "ws";
    const socket = new WebSocket(`${scheme}://${location.host}/ws`);
    state.socket = socket;
    socket.onopen = () => setConnection("live", "ok");
    socket.onclose = () => {
      setConnection("disconnected: retrying", "bad");
      setTimeout(connect, 1000);
    };
    socket.onmessage = (event) => receive(JSON.parse(event.data));
  }

  // A hidden tab draws (and so acknowledges) nothing: say "alive" now and then, or the server
  // closes the page as idle after two minutes (docs/robustness.md).
  setInterval(() => send({op: "alive"}), 30000);

  function setConnection(text, kind) {
    const node = $("connection");
    node.textContent = text;
    node.className = `connection ${kind}`;
  }

  function send(message) {
    if (state.socket && state.socket.readyState === WebSocket.OPEN) {
      state.socket.send(JSON.stringify(message));
    }
  }

  /** A TMCL command through the module's command path; resolves with the server's reply. */
  function command(cmd, type = 0, motor = 0, value = 0) {
    const id = state.nextId++;
    return new Promise((resolve) => {
      state.replies.set(id, resolve);
      send({op: "command", id, module: state.slot, cmd, type, motor, value});
    });
  }

  function receive(message) {
    if (message.type === "hello") return onHello(message);
    if (message.type === "frame") return onFrame(message);
    if (message.type === "reply" || message.type === "error") {
      const resolve = state.replies.get(message.id);
      state.replies.delete(message.id);
      if (resolve) resolve(message);
      else if (message.type === "error") showStatus("program-status", message.message, false);
    }
  }

  // -- hello: build the page for the modules ---------------------------------------------------

  function onHello(hello) {
    state.hello = hello;
    state.wire = [];  // a new connection (or a reconnection) sends the kept lines again
    state.wireSkipped = 0;
    const select = $("module");
    select.replaceChildren(...hello.modules.map(
      (m) => el("option", {value: m.slot, text: `${m.slot} (${m.type})`})));
    const wanted = Number(new URLSearchParams(location.search).get("module"));
    const first = hello.modules.find((m) => m.slot === wanted) || hello.modules[0];
    select.value = first.slot;
    const clock = hello.clock === "real" ? `real clock × ${hello.speed}` : `${hello.clock} clock`;
    $("clock-kind").textContent = `(${clock})`;
    showModule(first.slot);
  }

  function showModule(slot) {
    const description = state.hello.modules.find((m) => m.slot === slot);
    state.slot = slot;
    state.description = description;
    state.frame = null;
    state.samples = {t: [], position: [], velocity: [], target: []};
    for (let i = 0; i < description.axes; i++) {
      state.samples.position.push([]);
      state.samples.velocity.push([]);
      state.samples.target.push([]);
    }
    state.listing = [];
    $("module-type").textContent = description.type;
    buildAxes(description);
    buildIo(description);
    buildParameters(description);
    renderListing();
    sendView();
  }

  function sendView() {
    send({op: "view", module: state.slot, parameters: $("parameters-panel").open});
  }

  // -- axes ------------------------------------------------------------------------------------

  function compact(value) {
    const size = Math.abs(value);
    if (size >= 1e6) return `${+(value / 1e6).toFixed(2)}M`;
    if (size >= 1e4) return `${+(value / 1e3).toFixed(1)}k`;
    return `${value}`;
  }

  function buildAxes(description) {
    for (const plot of state.plots) plot.destroy();
    state.plots = [];
    const grid = $("axis-grid");
    grid.replaceChildren();
    for (let axis = 0; axis < description.axes; axis++) {
      const switches = el("span", {class: "switches"},
        ...["left", "home", "right"].map((name) => el("button", {
          class: "switch", "data-switch": name, title: `${name} switch: click to press or let go`,
          text: name[0].toUpperCase(),
          onclick: () => send({op: "switch", module: state.slot, axis, name})})));
      const load = el("input", {type: "range", min: 0, max: description.load_max, value: 500,
                                class: "load", title: "load (stallGuard2 value where no load zone lies)"});
      load.addEventListener("change", () =>
        send({op: "load", module: state.slot, axis, value: Number(load.value)}));
      const card = el("div", {class: "axis", id: `axis-${axis}`},
        el("div", {class: "axis-head"},
          el("b", {text: `Axis ${axis}`}), el("span", {class: "mode"}), el("span", {class: "reached"}),
          switches),
        el("div", {class: "legend"},
          el("span", {class: "key key-position", text: "position"}),
          el("span", {class: "key key-target", text: "target"}),
          el("span", {class: "key key-velocity", text: "velocity"}),
          el("span", {class: "key key-limit", text: "± max speed (AP 4)"})),
        el("div", {class: "plot"}),
        el("div", {class: "readout"},
          el("span", {}, "pos ", el("b", {class: "position"})),
          el("span", {}, "target ", el("b", {class: "target"})),
          el("span", {}, "vel ", el("b", {class: "velocity"})),
          el("span", {}, "vmax ", el("b", {class: "max-speed"}))),
        el("div", {class: "readout"},
          el("span", {}, "current ", el("b", {class: "current"})),
          el("span", {class: "currents"}),
          el("span", {}, "RFS ", el("b", {class: "rfs"}))),
        el("div", {class: "readout"},
          el("label", {}, "load ", load), el("span", {class: "load-value"}),
          el("span", {class: "errors"})));
      grid.append(card);
      state.plots.push(makePlot(card.querySelector(".plot")));
    }
  }

  function makePlot(container) {
    const width = Math.max(240, container.clientWidth || 360);
    const options = {
      width, height: 170,
      legend: {show: false},
      cursor: {drag: {x: false, y: false}},
      scales: {x: {time: false}, pos: {auto: true}, vel: {auto: true}},
      axes: [
        {scale: "x", size: 28, values: (u, values) => values.map((v) => v.toFixed(1))},
        {scale: "pos", stroke: POSITION, size: 52, values: (u, values) => values.map(compact)},
        {scale: "vel", side: 1, stroke: VELOCITY, size: 52, grid: {show: false},
         values: (u, values) => values.map(compact)},
      ],
      series: [
        {label: "t"},
        {label: "position", scale: "pos", stroke: POSITION, width: 2},
        {label: "target", scale: "pos", stroke: TARGET, width: 1, dash: [6, 4]},
        {label: "velocity", scale: "vel", stroke: VELOCITY, width: 1.5},
        {label: "+vmax", scale: "vel", stroke: LIMIT, width: 1, dash: [3, 3]},
        {label: "-vmax", scale: "vel", stroke: LIMIT, width: 1, dash: [3, 3]},
      ],
    };
    const plot = new uPlot(options, [[], [], [], [], [], []], container);
    new ResizeObserver(() => {
      const w = container.clientWidth;
      if (w && Math.abs(w - plot.width) > 2) plot.setSize({width: w, height: 170});
    }).observe(container);
    return plot;
  }

  function firstIndexAtOrAfter(times, t) {
    let lo = 0, hi = times.length;
    while (lo < hi) {
      const mid = (lo + hi) >> 1;
      if (times[mid] < t) lo = mid + 1; else hi = mid;
    }
    return lo;
  }

  function drawPlots() {
    const samples = state.samples, frame = state.frame;
    if (!frame || !samples.t.length) return;
    const end = samples.t[samples.t.length - 1];
    const start = firstIndexAtOrAfter(samples.t, end - state.windowS);
    const t = samples.t.slice(start);
    state.plots.forEach((plot, axis) => {
      const vmax = frame.axes[axis].max_speed;
      plot.setData([t, samples.position[axis].slice(start), samples.target[axis].slice(start),
                    samples.velocity[axis].slice(start), t.map(() => vmax), t.map(() => -vmax)], false);
      plot.setScale("x", {min: Math.min(end - state.windowS, t[0]), max: end});
    });
  }

  function drawAxes(frame) {
    frame.axes.forEach((axis, index) => {
      const card = $(`axis-${index}`);
      if (!card) return;
      const set = (selector, text) => setText(card.querySelector(selector), text);
      set(".mode", axis.mode);
      set(".reached", axis.reached ? "reached" : "");
      set(".position", axis.position);
      set(".target", axis.target);
      set(".velocity", axis.velocity);
      set(".max-speed", axis.max_speed);
      set(".current", axis.current);
      set(".currents", `(run ${axis.run_current}, standby ${axis.standby_current}${axis.standby ? ", in standby" : ""})`);
      set(".rfs", axis.rfs ? axis.rfs_phase : "idle");
      set(".load-value", `${axis.free_load} (reading ${axis.load})`);
      set(".errors", axis.errors ? `errors 0x${axis.errors.toString(16)}` : "");
      for (const button of card.querySelectorAll(".switch")) {
        const name = button.dataset.switch;
        button.classList.toggle("active", Boolean(axis[name]));
        button.classList.toggle("held", axis.held.includes(name));
      }
      const load = card.querySelector(".load");
      setValue(load, axis.free_load);
    });
  }

  // -- I/O -------------------------------------------------------------------------------------

  function buildIo(description) {
    $("digital-inputs").replaceChildren(...Array.from({length: description.inputs}, (_, port) =>
      el("button", {class: "chip input", "data-port": port, text: `IN${port}`,
                    title: "click to switch the input",
                    onclick: (event) => send({op: "input", module: state.slot, port,
                                              active: !event.currentTarget.classList.contains("on")})})));
    $("analog-inputs").replaceChildren(...Array.from({length: description.analog_inputs}, (_, port) => {
      const slider = el("input", {type: "range", min: 0, max: description.analog_full_scale, value: 0,
                                  "data-port": port});
      slider.addEventListener("change", () =>
        send({op: "analog", module: state.slot, port, value: Number(slider.value)}));
      return el("div", {class: "analog"}, el("span", {text: `AIN${port} `}), slider,
                el("b", {class: "analog-value", "data-port": port}));
    }));
    $("outputs").replaceChildren(...Array.from({length: description.outputs}, (_, port) =>
      el("span", {class: "chip lamp", "data-port": port, text: `OUT${port}`})));
  }

  function drawIo(io) {
    for (const button of $("digital-inputs").children) {
      button.classList.toggle("on", Boolean(io.inputs[button.dataset.port]));
    }
    for (const slider of $("analog-inputs").querySelectorAll("input")) {
      setValue(slider, io.analog[slider.dataset.port]);
    }
    for (const value of $("analog-inputs").querySelectorAll(".analog-value")) {
      setText(value, io.analog[value.dataset.port]);
    }
    for (const lamp of $("outputs").children) {
      lamp.classList.toggle("on", Boolean(io.outputs[lamp.dataset.port]));
    }
    setText($("supply"), io.supply.toFixed(1));
  }

  // -- parameters ------------------------------------------------------------------------------

  function valueCell(row, write) {
    if (!row.access.includes("W")) return el("td", {class: "value"});
    const input = el("input", {type: "text", inputmode: "numeric", class: "value-input",
                               title: `${row.title}: ${row.min}..${row.max}`});
    const submit = () => {
      const text = input.value.trim();
      if (!/^-?\d+$/.test(text)) return flash(input, false, `not a number: ${text}`);
      write(Number(text)).then((reply) => flash(input, reply.status === 100,
                                                reply.text || reply.message));
    };
    input.addEventListener("keydown", (event) => {
      if (event.key === "Enter") { submit(); input.blur(); }
      if (event.key === "Escape") input.blur();
    });
    return el("td", {class: "value editable"}, input);
  }

  function flash(input, ok, text) {
    input.classList.remove("ok", "refused");
    void input.offsetWidth;  // restart the animation
    input.classList.add(ok ? "ok" : "refused");
    showStatus("parameter-status", text, ok);
  }

  function showStatus(id, text, ok) {
    const node = $(id);
    node.textContent = text || "";
    node.classList.toggle("refused", !ok);
  }

  function buildParameters(description) {
    const table = $("axis-parameters");
    const head = el("tr", {}, el("th", {text: "No."}), el("th", {text: "name"}),
      ...Array.from({length: description.axes}, (_, a) => el("th", {text: `axis ${a}`})));
    const rows = description.axis_parameters.map((row) => el("tr", {"data-number": row.number},
      el("td", {class: "number", text: row.number}),
      el("td", {class: "name", text: row.name, title: row.title}),
      ...Array.from({length: description.axes}, (_, axis) =>
        valueCell(row, (value) => command(5, row.number, axis, value)))));
    table.replaceChildren(el("thead", {}, head), el("tbody", {}, ...rows));
    const titles = {0: "Global parameters (bank 0)", 2: "User variables (bank 2)",
                    3: "Interrupt configuration (bank 3)"};
    $("global-parameters").replaceChildren(...Object.entries(description.banks).map(([bank, table]) =>
      el("div", {},
        el("h3", {text: titles[bank] || `Global parameters (bank ${bank})`}),
        el("table", {class: "params", id: `bank-${bank}`},
          el("thead", {}, el("tr", {}, el("th", {text: "No."}), el("th", {text: "name"}),
                                  el("th", {text: "value"}))),
          el("tbody", {}, ...table.map((row) => el("tr", {"data-number": row.number},
            el("td", {class: "number", text: row.number}),
            el("td", {class: "name", text: row.name, title: row.title}),
            valueCell(row, (value) => command(9, row.number, Number(bank), value)))))))));
  }

  function setCell(cell, value) {
    if (!cell) return;
    const shown = value === null || value === undefined ? "" : String(value);
    const input = cell.querySelector("input");
    if (input) {
      if (document.activeElement !== input && input.value !== shown) input.value = shown;
    } else if (cell.textContent !== shown) {
      cell.textContent = shown;
    }
  }

  function drawParameters(parameters) {
    for (const row of $("axis-parameters").tBodies[0].rows) {
      const values = parameters.axis[row.dataset.number];
      if (!values) continue;
      values.forEach((value, axis) => setCell(row.cells[2 + axis], value));
    }
    for (const [bank, values] of Object.entries(parameters.banks)) {
      const table = $(`bank-${bank}`);
      if (!table) continue;
      for (const row of table.tBodies[0].rows) setCell(row.cells[2], values[row.dataset.number]);
    }
  }

  // -- program ---------------------------------------------------------------------------------

  function renderListing() {
    const list = $("listing");
    if (!state.listing.length) {
      list.replaceChildren(el("li", {class: "empty", text: "(program memory is empty)"}));
      return;
    }
    list.replaceChildren(...state.listing.map(([address, label, text]) =>
      el("li", {"data-address": address, title: "click: breakpoint on/off",
                onclick: () => toggleBreakpoint(address)},
        el("span", {class: "gutter"}),
        el("span", {class: "address", text: address}),
        el("span", {class: "label", text: label ? `${label}:` : ""}),
        el("span", {class: "code", text}))));
    state.shownPc = null;
  }

  function toggleBreakpoint(address) {
    const set = !(state.frame && state.frame.program.breakpoints.includes(address));
    send({op: "breakpoint", module: state.slot, address, set});
  }

  function drawProgram(program) {
    const text = (id, value) => setText($(id), value);
    text("reg-state", program.state + (program.protected ? " (read-protected: hosts read empty cells)" : ""));
    text("reg-pc", program.pc);
    text("reg-a", program.accumulator);
    text("reg-x", program.x);
    text("reg-wait", program.wait || "–");
    text("reg-executed", program.executed);
    for (const id of ["reg-flags", "reg-errors"]) {
      for (const chip of $(id).children) chip.classList.toggle("on", Boolean(program.flags[chip.textContent]));
    }
    text("reg-stack", program.stack.length ? program.stack.join(" › ") : "empty");
    const vectors = state.description.vectors;
    const name = (v) => vectors[v] || v;
    const irq = program.interrupts;
    text("reg-interrupts", [
      irq.global ? "EI 255 (on)" : "DI 255 (off)",
      irq.in_handler ? "in a handler" : "",
      irq.enabled.length ? `enabled ${irq.enabled.map(name).join(" ")}` : "none enabled",
      irq.pending.length ? `pending ${irq.pending.map(name).join(" ")}` : "",
    ].filter(Boolean).join(" · "));
    const vectorText = Object.entries(irq.vectors).map(([v, a]) => `${name(v)} → ${a}`).join(", ");
    text("reg-vectors", vectorText || "none");
    text("reg-breakpoints", program.breakpoints.length ? program.breakpoints.join(", ") : "none");
    const breakpoints = new Set(program.breakpoints);
    for (const line of $("listing").children) {
      const address = Number(line.dataset.address);
      line.classList.toggle("breakpoint", breakpoints.has(address));
      line.classList.toggle("current", address === program.pc);
    }
    if (state.shownPc !== program.pc) {
      state.shownPc = program.pc;
      const current = $("listing").querySelector("li.current");
      if (current) scrollIntoList(current);
    }
  }

  function scrollIntoList(line) {
    const list = $("listing");
    const top = line.offsetTop - list.offsetTop;
    if (top < list.scrollTop || top > list.scrollTop + list.clientHeight - line.offsetHeight) {
      list.scrollTop = top - list.clientHeight / 3;
    }
  }

  function programButton(id, opcode, type = 0, value = 0) {
    $(id).addEventListener("click", () => command(opcode, type, 0, value).then(
      (reply) => showStatus("program-status", reply.text || reply.message, reply.status === 100)));
  }

  // -- wire ------------------------------------------------------------------------------------

  function buildFlags() {
    const chips = (names) => names.map((name) => el("span", {class: "chip flag", text: name}));
    $("reg-flags").replaceChildren(...chips(["ZE", "NZ", "EQ", "NE", "GT", "GE", "LT", "LE"]));
    $("reg-errors").replaceChildren(...chips(["ETO", "EAL", "EDV", "EPO", "ESD"]));
  }

  function wireMatches(line) {
    const endpoint = $("wire-endpoint").value;
    const filter = $("wire-filter").value.trim().toLowerCase();
    if (endpoint && line[2] !== endpoint) return false;
    return !filter || line.join(" ").toLowerCase().includes(filter);
  }

  function wireRow(line) {
    const [sim, , endpoint, module, kind, text] = line;
    return el("tr", {class: `kind-${kind}`},
      el("td", {class: "number", text: sim.toFixed(6)}), el("td", {text: endpoint}),
      el("td", {class: "number", text: module}), el("td", {text: kind}), el("td", {text}));
  }

  function addWire(lines) {
    if (!lines.length) return;
    state.wire.push(...lines);
    if (state.wire.length > WIRE_KEEP) state.wire.splice(0, state.wire.length - WIRE_KEEP);
    const select = $("wire-endpoint");
    for (const line of lines) {
      if (!state.endpoints.has(line[2])) {
        state.endpoints.add(line[2]);
        select.append(el("option", {value: line[2], text: line[2]}));
      }
    }
    state.wireDirty = true;
  }

  function drawWire() {
    if (state.wireDirty && !$("wire-pause").checked &&
        performance.now() - state.wireShownAt >= WIRE_REFRESH_MS) renderWire();
  }

  function renderWire() {
    state.wireDirty = false;
    state.wireShownAt = performance.now();
    const matching = state.wire.filter(wireMatches);
    const rows = matching.slice($("wire-pause").checked ? -WIRE_PAUSED_ROWS : -WIRE_LIVE_ROWS);
    $("wire-table").tBodies[0].replaceChildren(...rows.map(wireRow));
    setText($("wire-count"), `${rows.length} shown, ${matching.length} of ${state.wire.length} kept match` +
      (state.wireSkipped ? `; ${state.wireSkipped} more not sent (too many to follow)` : ""));
    const box = document.querySelector(".wire-box");
    box.scrollTop = box.scrollHeight;
  }

  // -- frames ----------------------------------------------------------------------------------

  function onFrame(frame) {
    if (frame.module !== state.slot) {  // sent before the page switched modules
      send({op: "ack"});
      return;
    }
    state.frame = frame;
    state.frames++;
    const samples = state.samples, add = frame.samples;
    if (add.t.length) {
      samples.t.push(...add.t);
      for (let axis = 0; axis < samples.position.length; axis++) {
        samples.position[axis].push(...add.position[axis]);
        samples.velocity[axis].push(...add.velocity[axis]);
        samples.target[axis].push(...add.target[axis]);
      }
      const drop = firstIndexAtOrAfter(samples.t, samples.t[samples.t.length - 1] - KEEP_S);
      if (drop > 0) {
        samples.t.splice(0, drop);
        for (const series of [samples.position, samples.velocity, samples.target]) {
          for (const values of series) values.splice(0, drop);
        }
      }
    }
    if (frame.listing) {
      state.listing = frame.listing;
      renderListing();
    }
    state.wireSkipped += frame.wire_skipped;
    addWire(frame.wire);
    if (frame.parameters) drawParameters(frame.parameters);
    if (!state.drawPending) {
      state.drawPending = true;
      requestAnimationFrame(draw);
    }
  }

  function draw() {
    state.drawPending = false;
    const frame = state.frame;
    if (frame) {
      setText($("sim-time"), frame.t.toFixed(3));
      drawAxes(frame);
      drawPlots();
      drawIo(frame.io);
      drawProgram(frame.program);
    }
    drawWire();
    send({op: "ack"});  // drawn: the server may send the next frame
  }

  // -- wiring up -------------------------------------------------------------------------------

  $("module").addEventListener("change", (event) => showModule(Number(event.target.value)));
  $("window").addEventListener("change", (event) => {
    state.windowS = Number(event.target.value);
    drawPlots();
  });
  $("parameters-panel").addEventListener("toggle", sendView);
  $("wire-endpoint").addEventListener("change", renderWire);
  $("wire-filter").addEventListener("input", renderWire);
  $("wire-pause").addEventListener("change", renderWire);
  buildFlags();
  programButton("run", 129, 0);
  programButton("stop", 128);
  programButton("step", 130);
  programButton("reset", 131);

  /** For scripts and tests: the page's own state, and what its plots hold. */
  window.tmclDashboard = {
    state,
    send,
    command,
    frames: () => state.frames,
    plotted(axis) {
      const plot = state.plots[axis];
      if (!plot || !plot.data[0].length) return null;
      const last = plot.data[0].length - 1;
      return {t: plot.data[0][last], position: plot.data[1][last], target: plot.data[2][last],
              velocity: plot.data[3][last], maxSpeed: plot.data[4][last], points: last + 1};
    },
  };

  connect();
})();
