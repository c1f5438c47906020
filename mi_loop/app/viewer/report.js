// mi_loop's report viewer: draws the page's data (script#mi-loop-data, written by mi_loop.app.html_report)
// with three.js (the global THREE of three.min.js, inlined before this script). No network, no modules:
// the page works when opened from the file system.
//
// Hook for automated checks: after every draw the canvas carries data-drawn (the triangles three.js drew)
// and, in a sequence, data-frame (the frame shown).
(function () {
    "use strict";

    // Matplotlib's viridis, sRGB, 10 stops from 0 to 1.
    const VIRIDIS = [[68, 1, 84], [72, 40, 120], [62, 74, 137], [49, 104, 142], [38, 130, 142],
        [31, 158, 137], [53, 183, 121], [110, 206, 88], [181, 222, 43], [253, 231, 37]];
    const PLAIN = [0.62, 0.62, 0.6];                     // linear grey of the plain surface
    const SERIES_COLOURS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728"];

    function viridis(t) {                              // t in [0, 1] -> sRGB in [0, 1]
        const x = Math.min(Math.max(t, 0), 1) * (VIRIDIS.length - 1);
        const i = Math.min(Math.floor(x), VIRIDIS.length - 2), f = x - i;
        return VIRIDIS[i].map((a, c) => (a + f * (VIRIDIS[i + 1][c] - a)) / 255);
    }

    function toLinear(c) {
        return c <= 0.04045 ? c / 12.92 : Math.pow((c + 0.055) / 1.055, 2.4);
    }

    function bytesOf(b64) {
        if (Uint8Array.fromBase64) return Uint8Array.fromBase64(b64);
        const s = atob(b64), out = new Uint8Array(s.length);
        for (let i = 0; i < s.length; i++) out[i] = s.charCodeAt(i);
        return out;
    }

    // An array of html_report._array as a flat typed array (Uint32Array for indices, else Float32Array).
    function decode(a) {
        if (!a) return null;
        const buf = bytesOf(a.b64).buffer, cols = a.shape[1];
        if (a.kind === "u4") return new Uint32Array(buf);
        if (a.kind === "f4") return new Float32Array(buf);
        const q = a.kind === "q16" ? new Uint16Array(buf) : a.kind === "n16" ? new Int16Array(buf) : new Uint8Array(buf);
        const out = new Float32Array(q.length);
        if (a.kind === "q16") {
            for (let i = 0; i < q.length; i++) {
                const c = i % cols;
                out[i] = a.lo[c] + (a.hi[c] - a.lo[c]) * q[i] / 65535;
            }
        } else {
            const s = a.kind === "n16" ? 32767 : 255;
            for (let i = 0; i < q.length; i++) out[i] = q[i] / s;
        }
        return out;
    }

    function esc(s) {                                  // text for innerHTML
        return String(s).replace(/[&<>"']/g, c => ({"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;",
            "'": "&#39;"})[c]);
    }

    function percent(v) {
        const p = 100 * v;
        return (p === 0 ? "0" : p >= 10 ? p.toFixed(1) : p.toPrecision(2)) + " %";
    }

    const data = JSON.parse(document.getElementById("mi-loop-data").textContent);
    const canvas = document.getElementById("view");
    const T = data.frames;
    const P = decode(data.P), N = decode(data.N), C = decode(data.C);
    const D = data.fields.map(f => decode(f.d));      // per colouring by distance: (T k) values
    const k = P.length / (3 * T);                      // points per frame
    const cageP = data.cage ? decode(data.cage.P) : null;
    const state = {frame: 0, colour: D.length ? "field-0" : data.C ? "albedo" : "plain", playing: null};

    const renderer = new THREE.WebGLRenderer({canvas: canvas, antialias: true, preserveDrawingBuffer: true});
    renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
    const scene = new THREE.Scene();
    scene.background = new THREE.Color(0xf4f4f2);

    // The surface: one geometry whose attributes are refilled for each frame.
    const geometry = new THREE.BufferGeometry();
    geometry.setIndex(new THREE.BufferAttribute(decode(data.F), 1));
    geometry.setAttribute("position", new THREE.BufferAttribute(P.slice(0, 3 * k), 3));
    geometry.setAttribute("normal", new THREE.BufferAttribute(N.slice(0, 3 * k), 3));
    geometry.setAttribute("color", new THREE.BufferAttribute(new Float32Array(3 * k), 3));
    const surface = new THREE.Mesh(geometry, new THREE.MeshStandardMaterial({
        vertexColors: true, side: THREE.DoubleSide, roughness: 0.6, metalness: 0.0,
        polygonOffset: true, polygonOffsetFactor: 1, polygonOffsetUnits: 1}));
    scene.add(surface);

    function lines(positions, index, colour, opacity) {
        const g = new THREE.BufferGeometry();
        g.setAttribute("position", new THREE.BufferAttribute(positions, 3));
        if (index) g.setIndex(new THREE.BufferAttribute(index, 1));
        const m = new THREE.LineBasicMaterial({color: colour, transparent: opacity < 1, opacity: opacity});
        const l = new THREE.LineSegments(g, m);
        scene.add(l);
        return l;
    }

    const layers = {};
    if (data.points) {
        const g = new THREE.BufferGeometry();
        g.setAttribute("position", new THREE.BufferAttribute(decode(data.points), 3));
        layers.points = new THREE.Points(g, new THREE.PointsMaterial({color: 0x202020, size: 2,
            sizeAttenuation: false, transparent: true, opacity: 0.6}));
        scene.add(layers.points);
    }
    const n = data.cage ? data.cage.n : 0;
    if (data.cage) layers.cage = lines(cageP.slice(0, 3 * n), decode(data.cage.E), 0x303030, 0.55);
    if (data.creases) layers.creases = lines(decode(data.creases), null, 0xd62728, 1);
    if (data.frusta) layers.frusta = lines(decode(data.frusta), null, 0x1f5fbf, 1);

    // Lights: a hemisphere and a head light that follows the camera.
    scene.add(new THREE.HemisphereLight(0xffffff, 0x555566, 1.6));
    const camera = new THREE.PerspectiveCamera(35, 1, 0.01, 100);
    const head = new THREE.DirectionalLight(0xffffff, 1.6);
    head.position.set(0.3, 0.6, 1);
    camera.add(head);
    scene.add(camera);

    // Frame every frame's surface, seen from azimuth 35 and elevation 25 degrees (y up) as render.png is,
    // and the cameras as far as the surface stays at least half of the view across.
    function bounds(arrays) {
        const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
        arrays.forEach(X => {
            for (let i = 0; i < X.length; i++) {
                lo[i % 3] = Math.min(lo[i % 3], X[i]);
                hi[i % 3] = Math.max(hi[i % 3], X[i]);
            }
        });
        return {centre: new THREE.Vector3((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2),
            radius: Math.max(0.5 * Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]), 1e-9)};
    }
    const own = bounds([P]);
    const all = layers.frusta ? bounds([P, layers.frusta.geometry.attributes.position.array]) : own;
    const centre = own.centre, radius = Math.min(all.radius, 2 * own.radius);
    const distance = 1.1 * radius / Math.sin((35 / 2) * Math.PI / 180);
    const az = 35 * Math.PI / 180, el = 25 * Math.PI / 180;
    camera.position.set(centre.x + distance * Math.sin(az) * Math.cos(el), centre.y + distance * Math.sin(el),
        centre.z + distance * Math.cos(az) * Math.cos(el));
    camera.near = distance / 100;
    camera.far = 100 * (distance + radius);
    const controls = new THREE.OrbitControls(camera, canvas);
    controls.target.copy(centre);
    controls.update();

    let pending = false;
    function draw() {
        pending = false;
        renderer.render(scene, camera);
        canvas.dataset.drawn = String(renderer.info.render.triangles);
        if (data.kind === "sequence") canvas.dataset.frame = String(state.frame);
    }
    function redraw() {
        if (!pending) {
            pending = true;
            requestAnimationFrame(draw);
        }
    }
    controls.addEventListener("change", redraw);

    function resize() {
        const w = canvas.clientWidth, h = canvas.clientHeight;
        renderer.setSize(w, h, false);
        camera.aspect = w / Math.max(h, 1);
        camera.updateProjectionMatrix();
        redraw();
    }
    window.addEventListener("resize", resize);

    function colour() {
        const out = geometry.attributes.color.array, t = state.frame;
        if (state.colour.startsWith("field-")) {
            const f = Number(state.colour.slice(6)), top = data.fields[f].legend.top;
            for (let i = 0; i < k; i++) {
                const rgb = viridis(D[f][t * k + i] / top);
                for (let c = 0; c < 3; c++) out[3 * i + c] = toLinear(rgb[c]);
            }
        } else if (state.colour === "albedo") {
            const off = C.length === 3 * k ? 0 : 3 * k * t;
            out.set(C.subarray(off, off + 3 * k));
        } else {
            for (let i = 0; i < 3 * k; i++) out[i] = PLAIN[i % 3];
        }
        geometry.attributes.color.needsUpdate = true;
        legend();
    }

    function legend() {
        const box = document.getElementById("legend");
        if (!state.colour.startsWith("field-")) {
            box.hidden = true;
            return;
        }
        const L = data.fields[Number(state.colour.slice(6))].legend, stops = [];
        for (let i = 0; i <= 10; i++) stops.push(`rgb(${viridis(i / 10).map(c => Math.round(255 * c)).join(",")})`);
        const ticks = [0, 0.5, 1].map(f => {
            const label = (f === 1 && L.max > L.top ? "\u2265 " : "") + percent(f * L.top);
            return `<span style="left:${100 * f}%">${label}</span>`;
        }).join("");
        box.hidden = false;
        box.innerHTML = `<div class="legend-title">${esc(L.title)}</div>` +
            `<div class="legend-bar" style="background:linear-gradient(to right,${stops.join(",")})"></div>` +
            `<div class="legend-ticks">${ticks}</div>` +
            `<div class="legend-note">largest: ${percent(L.max)}</div>`;
    }

    function setFrame(t) {
        state.frame = Math.min(Math.max(Math.round(t), 0), T - 1);
        const t0 = 3 * k * state.frame;
        geometry.attributes.position.array.set(P.subarray(t0, t0 + 3 * k));
        geometry.attributes.normal.array.set(N.subarray(t0, t0 + 3 * k));
        geometry.attributes.position.needsUpdate = geometry.attributes.normal.needsUpdate = true;
        geometry.computeBoundingSphere();
        if (layers.cage) {
            const a = layers.cage.geometry.attributes.position;
            a.array.set(cageP.subarray(3 * n * state.frame, 3 * n * (state.frame + 1)));
            a.needsUpdate = true;
            layers.cage.geometry.computeBoundingSphere();
        }
        colour();
        if (data.kind === "sequence") {
            document.getElementById("frame").value = String(state.frame);
            document.getElementById("frame-label").textContent =
                `frame ${state.frame + 1} / ${T}: ${data.names[state.frame]}`;
            plots();
        }
        redraw();
    }

    // Per-frame plots of a sequence (SVG), the current frame marked; a click chooses the frame.
    function plots() {
        const box = document.getElementById("plots");
        if (!box || !data.plots) return;
        const W = 420, H = 150, m = {l: 56, r: 10, t: 20, b: 24};
        const frames = data.plots.frames, x0 = frames[0], x1 = Math.max(frames[frames.length - 1], x0 + 1);
        const X = f => m.l + (W - m.l - m.r) * (f - x0) / (x1 - x0);
        box.innerHTML = data.plots.panels.map(panel => {
            const all = Object.values(panel.series).flat().filter(v => v !== null);
            let y0 = Math.min(0, ...all), y1 = Math.max(...all);
            if (!(y1 > y0)) y1 = y0 + 1;
            const Y = v => H - m.b - (H - m.t - m.b) * (v - y0) / (y1 - y0);
            let svg = `<line x1="${m.l}" y1="${H - m.b}" x2="${W - m.r}" y2="${H - m.b}" class="axis"/>` +
                `<line x1="${m.l}" y1="${m.t}" x2="${m.l}" y2="${H - m.b}" class="axis"/>` +
                `<text x="${m.l - 4}" y="${Y(y1) + 4}" class="tick" text-anchor="end">${y1.toPrecision(2)}</text>` +
                `<text x="${m.l - 4}" y="${Y(y0) + 4}" class="tick" text-anchor="end">${y0.toPrecision(2)}</text>` +
                `<text x="${X(x0)}" y="${H - 6}" class="tick" text-anchor="middle">${x0}</text>` +
                `<text x="${X(x1)}" y="${H - 6}" class="tick" text-anchor="middle">${x1}</text>` +
                `<text x="${W / 2}" y="13" class="title" text-anchor="middle">${esc(panel.title)}</text>`;
            const fx = X(frames[state.frame]);
            svg += `<line x1="${fx}" y1="${m.t}" x2="${fx}" y2="${H - m.b}" class="marker"/>`;
            Object.entries(panel.series).forEach(([label, values], s) => {
                const colourOf = SERIES_COLOURS[s % SERIES_COLOURS.length];
                const pts = values.map((v, i) => v === null ? null : `${X(frames[i])},${Y(v)}`).filter(p => p);
                svg += `<polyline points="${pts.join(" ")}" fill="none" stroke="${colourOf}" stroke-width="1.5"/>`;
                const v = values[state.frame];
                if (v !== null) svg += `<circle cx="${fx}" cy="${Y(v)}" r="3.5" fill="${colourOf}"/>`;
                svg += `<text x="${W - m.r}" y="${m.t + 12 + 12 * s}" class="tick" text-anchor="end" ` +
                    `style="fill:${colourOf}">${esc(label)}</text>`;
            });
            return `<svg class="plot" viewBox="0 0 ${W} ${H}" data-x0="${m.l}" data-x1="${W - m.r}">${svg}</svg>`;
        }).join("");
        box.querySelectorAll("svg").forEach(svg => svg.addEventListener("click", event => {
            const r = svg.getBoundingClientRect(), x = (event.clientX - r.left) * W / r.width;
            const f = x0 + (x - m.l) / (W - m.l - m.r) * (x1 - x0);
            let best = 0;
            frames.forEach((g, i) => { if (Math.abs(g - f) < Math.abs(frames[best] - f)) best = i; });
            stop();
            setFrame(best);
        }));
    }

    function stop() {
        if (state.playing !== null) clearInterval(state.playing);
        state.playing = null;
        const b = document.getElementById("play");
        if (b) b.textContent = "play";
    }

    const select = document.getElementById("colour");
    select.value = state.colour;
    select.addEventListener("change", () => { state.colour = select.value; colour(); redraw(); });
    Object.entries(layers).forEach(([key, object]) => {
        const box = document.getElementById(`show-${key}`);
        object.visible = box.checked;
        box.addEventListener("change", () => { object.visible = box.checked; redraw(); });
    });
    if (data.kind === "sequence") {
        const slider = document.getElementById("frame");
        slider.addEventListener("input", () => { stop(); setFrame(Number(slider.value)); });
        document.getElementById("play").addEventListener("click", event => {
            if (state.playing !== null) return stop();
            event.target.textContent = "pause";
            state.playing = setInterval(() => setFrame((state.frame + 1) % T), 1000 / Math.min(data.fps, 60));
        });
    }
    resize();
    setFrame(0);
})();
