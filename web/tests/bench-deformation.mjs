// Measures the viewer's deformation update in Chromium, beside the paper's Table 1.
//
//   npm run bench   (builds and starts the server, debug profile; BENCH_RELEASE=1 for release,
//                    SOFTHAPTIC_URL to use a server that is already running; BENCH_SCENE=FILE
//                    to start it with a scene file, e.g. scenes/cone.toml, instead of the
//                    built-in default)
//
// For flat square grids of the paper's sizes (40² … 100² vertices) and for the scene's render
// mesh, times MeshDeformer.apply (restore the previous dimple, move the new one, analytic
// normals) over a press that slides a little each update, and prints the median. Then, on
// 100 000 vertices, each deformation profile (`paper`, the paper's Bézier, and `fem`, the
// calibration's FEM surface from the scene's table) at several depths, on the CPU path and on
// the vertex shader's (the CPU's part of an update, and the draw bent and at rest). Then lets the live page
// run and reports its frame rate, the frames it receives per second, and the median
// deformation time it measured while drawing. Nothing here is asserted: it is a measurement.
import { existsSync, readFileSync } from 'node:fs';
import os from 'node:os';
import { fileURLToPath } from 'node:url';

import { launchBrowser } from './browser.mjs';
import { startServer } from './server.mjs';

const PAPER_TABLE_1 = [
  // vertices, mean ms, sd ms (He & Choi, Table 1: computation time per step)
  [1600, 0.154, 0.014],
  [2500, 0.231, 0.012],
  [3600, 0.325, 0.014],
  [4900, 0.426, 0.013],
  [6400, 0.551, 0.012],
  [8100, 0.696, 0.025],
  [10000, 0.856, 0.016],
];
const UPDATES = Number(process.env.BENCH_UPDATES ?? 400);

/**
 * The drawn surface's error against the FEM surface, from the calibration report's table of the
 * scene's tool (calibration/report/surface_<tool>.csv, neo-Hookean rows: the FEM the scene's table
 * comes from): for each depth in millimetres, each profile's worst |drawn − FEM| in millimetres,
 * the `fem` profile's with the depth's own row held out (drawn from the rows beside it, as any
 * depth between the table's rows is: at a table depth the row is the FEM itself). Empty when the
 * report has no table for this tool.
 */
function surfaceErrorsMm(tool) {
  const name = tool.shape === 'sphere' ? 'sphere10' : 'cone10_45';
  const path = fileURLToPath(new URL(`../../calibration/report/surface_${name}.csv`, import.meta.url));
  if (!existsSync(path)) return new Map();
  const [header, ...rows] = readFileSync(path, 'utf8').trim().split('\n');
  const column = Object.fromEntries(header.split(',').map((h, i) => [h, i]));
  const errors = new Map();
  for (const row of rows) {
    const cells = row.split(',');
    if (cells[column.law] !== 'neo_hookean') continue;
    errors.set(Number(cells[column.depth_mm]), {
      paper: Math.abs(Number(cells[column.paper_worst_error_mm])),
      fem: Math.abs(Number(cells[column.fem_held_out_worst_error_mm])),
    });
  }
  return errors;
}
const LIVE_SECONDS = Number(process.env.BENCH_LIVE_SECONDS ?? 8);
/**
 * The scene file the server is started with (a path from the repository's root, as `--scene`
 * takes it); unset: the built-in default scene (the 10 mm sphere). The tool, the calibration
 * table and the render mesh timed are the scene's.
 */
const SCENE = process.env.BENCH_SCENE || null;
const DRAWS = Number(process.env.BENCH_DRAWS ?? 15);

/** Runs inside the page: times `updates` deformation updates on a grid or the render mesh. */
async function timeInPage({ kind, side, updates, profile = 'paper', depthM = 0.004, deformedRadiusM = 0.02 }) {
  const { contactRadius, exactSphereContactRadius, surfaceFamilyFromJson, toolFromJson } =
    await import('/src/deformation.js');
  const { MeshDeformer } = await import('/src/deformer.js');
  const { flatGrid, parseRenderMesh } = await import('/src/mesh.js');
  const scene = await (await fetch('/api/scene')).json();
  const tool = toolFromJson(scene.tool);
  // The `fem` profile needs the table's tabulated surface; without one there is nothing to time.
  if (profile === 'fem' && !scene.calibration.surface) return null;
  const surface = profile === 'fem' ? surfaceFamilyFromJson(scene.calibration.surface) : null;
  let mesh;
  let centre;
  let normal;
  if (kind === 'grid') {
    // A 100 mm square, the size of the paper's calibration block's top face.
    mesh = flatGrid(side, 0.1);
    centre = [0, 0, 0];
    normal = [0, 1, 0];
  } else {
    const desc = scene.render_meshes[0];
    mesh = parseRenderMesh(await (await fetch(desc.url)).arrayBuffer(), desc.name);
    // Press where the mesh is highest, along that vertex's normal.
    let top = 0;
    for (let i = 1; i < mesh.positions.length / 3; i++)
      if (mesh.positions[3 * i + 1] > mesh.positions[3 * top + 1]) top = i;
    centre = Array.from(mesh.positions.subarray(3 * top, 3 * top + 3));
    normal = Array.from(mesh.normals.subarray(3 * top, 3 * top + 3));
  }
  const deformer = new MeshDeformer(mesh.positions, mesh.normals);
  const positions = Float32Array.from(mesh.positions);
  const normals = Float32Array.from(mesh.normals);
  // By default a 4 mm press (the paper's valid depth for a 10 mm sphere is 4.3 mm), R_d = 20 mm.
  const contact = {
    inContact: true,
    depthM,
    // As the scenes stream it: their sphere models use the exact sphere.
    contactRadiusM:
      tool.shape === 'sphere' ? exactSphereContactRadius(tool.radiusM, depthM) : contactRadius(tool, depthM),
    deformedRadiusM,
    point: [0, 0, 0],
    normal,
  };
  // performance.now() is coarsened to 0.1 ms in a page, so updates are timed in batches of 10
  // and the median is taken over the batch means.
  const batch = 10;
  const batches = Math.max(1, Math.floor(updates / batch));
  const means = new Float64Array(batches);
  let moved = 0;
  let k = 0;
  const step = () => {
    // Slide ±1 mm so each update restores the last dimple and moves a new one.
    contact.point[0] = centre[0] + 0.001 * Math.sin(k * 0.3);
    contact.point[1] = centre[1];
    contact.point[2] = centre[2] + 0.001 * Math.cos(k * 0.3);
    k++;
    deformer.apply(positions, normals, contact, tool, surface);
  };
  for (let w = 0; w < 50; w++) step(); // warm-up: let the JIT compile apply()
  for (let b = 0; b < batches; b++) {
    const t0 = performance.now();
    for (let j = 0; j < batch; j++) step();
    means[b] = (performance.now() - t0) / batch;
    moved = deformer.movedCount;
  }
  const sorted = Float64Array.from(means).sort();
  const meanMs = means.reduce((a, b) => a + b, 0) / batches;
  return { vertices: deformer.vertexCount, medianMs: sorted[batches >> 1], meanMs, moved };
}

/**
 * Runs inside the page: the GPU path (`shaderdeform.js`) on the 100 000-vertex grid. Times the
 * CPU's part of an update (the profile's radial table, its copy into the texture, the uniforms)
 * like `timeInPage`, then the draw of the grid in a WebGL canvas of its own, bent by the shader
 * and at rest (reach 0), each draw waited for with a one-pixel read, median over `draws`.
 */
async function timeGpuInPage({ profile, depthM, deformedRadiusM, updates, draws }) {
  const THREE = await import('three');
  const {
    contactRadius,
    exactSphereContactRadius,
    profileSetup,
    profileTable,
    surfaceFamilyFromJson,
    surfaceSetup,
    surfaceTable,
    toolFromJson,
  } = await import('/src/deformation.js');
  const { DeformationTable } = await import('/src/shaderdeform.js');
  const { flatGrid } = await import('/src/mesh.js');
  const scene = await (await fetch('/api/scene')).json();
  const tool = toolFromJson(scene.tool);
  if (profile === 'fem' && !scene.calibration.surface) return null;
  const surface = profile === 'fem' ? surfaceFamilyFromJson(scene.calibration.surface) : null;
  // As the scenes stream it: their sphere models use the exact sphere.
  const contactRadiusM =
    tool.shape === 'sphere' ? exactSphereContactRadius(tool.radiusM, depthM) : contactRadius(tool, depthM);
  const grid = flatGrid(317, 0.1);
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', new THREE.BufferAttribute(grid.positions, 3));
  geometry.setAttribute('normal', new THREE.BufferAttribute(grid.normals, 3));
  geometry.setIndex(new THREE.BufferAttribute(grid.indices, 1));
  const material = new THREE.MeshStandardMaterial({ color: 0xd98c8c, roughness: 0.55 });
  const table = new DeformationTable();
  const uniforms = table.install(material, [0.25, 0.45, 1.0]);
  const view = new THREE.Scene();
  view.add(new THREE.HemisphereLight(0xdde6ff, 0x2a2018, 1.2));
  view.add(new THREE.Mesh(geometry, material));
  const camera = new THREE.PerspectiveCamera(40, 320 / 200, 0.001, 10);
  camera.position.set(0.08, 0.09, 0.12);
  camera.lookAt(0, 0, 0);
  const canvas = document.createElement('canvas');
  // Small, so that the frame's cost is mostly the vertices' and not the pixels'.
  canvas.width = 320;
  canvas.height = 200;
  const renderer = new THREE.WebGLRenderer({ canvas, antialias: false });
  const prepared = {};
  const radial = {};
  const point = [0, 0, 0];
  const normal = [0, 1, 0];
  let k = 0;
  const update = () => {
    point[0] = 0.001 * Math.sin(k * 0.3);
    point[2] = 0.001 * Math.cos(k * 0.3);
    k++;
    if (surface) surfaceTable(surfaceSetup(surface, tool, depthM, prepared), radial);
    else profileTable(profileSetup(tool, depthM, contactRadiusM, deformedRadiusM, prepared), radial);
    table.update(radial);
    table.place(uniforms, true, point, normal, 0);
  };
  for (let w = 0; w < 50; w++) update();
  const batch = 10;
  const batches = Math.max(1, Math.floor(updates / batch));
  const means = [];
  for (let b = 0; b < batches; b++) {
    const t0 = performance.now();
    for (let j = 0; j < batch; j++) update();
    means.push((performance.now() - t0) / batch);
  }
  means.sort((a, b) => a - b);
  const gl = renderer.getContext();
  const pixel = new Uint8Array(4);
  const drawMs = (bent) => {
    const times = [];
    for (let f = 0; f < draws + 2; f++) {
      if (bent) update();
      else table.place(uniforms, false, point, normal, 0);
      const t0 = performance.now();
      renderer.render(view, camera);
      gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, pixel);
      if (f >= 2) times.push(performance.now() - t0); // the first draws compile the shader
    }
    times.sort((a, b) => a - b);
    return times[times.length >> 1];
  };
  const bentMs = drawMs(true);
  const restMs = drawMs(false);
  renderer.dispose();
  // The context too, or the eight of them would linger beside the live page's (and slow it).
  renderer.forceContextLoss();
  geometry.dispose();
  material.dispose();
  table.texture.dispose();
  return { updateMs: means[means.length >> 1], bentMs, restMs, reachMm: table.reachM * 1000 };
}

if (SCENE !== null && process.env.SOFTHAPTIC_URL) {
  // A running server has its own scene; timing it under another scene's name would mislead.
  throw new Error('BENCH_SCENE starts a server with that scene; unset SOFTHAPTIC_URL to use it');
}
const server = await startServer({
  release: Boolean(process.env.BENCH_RELEASE),
  extraArgs: ['--no-realtime', '--no-record', ...(SCENE === null ? [] : ['--scene', SCENE])],
});
const browser = await launchBrowser();
try {
  const page = await browser.newPage({ viewport: { width: 1280, height: 800 } });
  page.on('pageerror', (e) => console.error(`page error: ${e.message}`));
  await page.goto(server.url);
  await page.waitForFunction(() => window.__softhaptic?.ready(), null, { timeout: 60000 });
  await page.evaluate(() => window.__softhaptic.animation(false)); // the live view must not compete

  const load = os
    .loadavg()
    .map((x) => x.toFixed(1))
    .join(' ');
  console.log(`Host: ${os.cpus().length} CPUs (${os.cpus()[0]?.model ?? 'unknown'}), load average ${load}`);
  const sceneTool = await page.evaluate(async () => (await (await fetch('/api/scene')).json()).tool);
  const toolWords =
    sceneTool.shape === 'cone'
      ? `${((sceneTool.half_angle_rad * 180) / Math.PI).toFixed(0)}° cone, base radius ${(sceneTool.radius_m * 1000).toFixed(0)} mm`
      : `${(sceneTool.radius_m * 1000).toFixed(0)} mm ${sceneTool.shape}`;
  console.log(`Scene: ${SCENE ?? 'the built-in default'} (tool: ${toolWords})`);
  console.log(
    `Deformation update in Chromium on the CPU path, MeshDeformer (${UPDATES} updates each; 4 mm press, R_d = 20 mm)`,
  );
  console.log('');
  console.log('| vertices | moved | median ms | mean ms | paper Table 1 mean ms (SD) |');
  console.log('|---:|---:|---:|---:|---:|');
  for (const [vertices, paperMs, paperSd] of PAPER_TABLE_1) {
    const side = Math.round(Math.sqrt(vertices));
    const r = await page.evaluate(timeInPage, { kind: 'grid', side, updates: UPDATES });
    console.log(
      `| ${r.vertices} | ${r.moved} | ${r.medianMs.toFixed(3)} | ${r.meanMs.toFixed(3)} | ${paperMs.toFixed(3)} (${paperSd.toFixed(3)}) |`,
    );
  }
  // The dense worst case: 100 000 vertices on the same 100 mm square (1 vertex per 0.1 mm²).
  const dense = await page.evaluate(timeInPage, { kind: 'grid', side: 317, updates: UPDATES });
  console.log(
    `| ${dense.vertices} (grid) | ${dense.moved} | ${dense.medianMs.toFixed(3)} | ${dense.meanMs.toFixed(3)} | — |`,
  );
  const r = await page.evaluate(timeInPage, { kind: 'render', side: 0, updates: UPDATES });
  console.log(`| ${r.vertices} (render mesh) | ${r.moved} | ${r.medianMs.toFixed(3)} | ${r.meanMs.toFixed(3)} | — |`);
  console.log('');
  console.log(
    "Each profile on the 100 000-vertex grid (100 mm square, the scene's tool pressing its centre), R_d from the",
  );
  console.log("scene's table; `fem` draws the tabulated FEM surface (each point sunk and slid sideways as");
  console.log("the FEM's moved) out to where it settles, the block's side plus its 10 mm ramp at depth, so");
  console.log('it moves more vertices than R_d holds:');
  console.log('');
  console.log('| profile | δ (mm) | R_d (mm) | moved | median ms | mean ms | worst error vs FEM, held out (mm) |');
  console.log('|---|---:|---:|---:|---:|---:|---:|');
  const table = await page.evaluate(async () => (await (await fetch('/api/scene')).json()).calibration);
  const errors = surfaceErrorsMm(table.tool);
  const errorAt = (profile, depthMm) => errors.get(depthMm)?.[profile]?.toFixed(3) ?? '—';
  const fit = table.fit;
  const deformedRadius = (d) =>
    d < fit.breakpoint_m
      ? fit.linear[0] + fit.linear[1] * d
      : fit.quadratic[0] + fit.quadratic[1] * d + fit.quadratic[2] * d * d;
  for (const profile of ['paper', 'fem']) {
    for (const depthMm of [1, 4, 8, 10]) {
      const depthM = depthMm / 1000;
      const deformedRadiusM = Math.max(0, deformedRadius(depthM));
      const p = await page.evaluate(timeInPage, {
        kind: 'grid',
        side: 317,
        updates: UPDATES,
        profile,
        depthM,
        deformedRadiusM,
      });
      if (p === null) {
        console.log(`| ${profile} | ${depthMm} | — | — | (the scene's table carries no surface) | — | — |`);
        continue;
      }
      console.log(
        `| ${profile} | ${depthMm} | ${(deformedRadiusM * 1000).toFixed(1)} | ${p.moved} | ${p.medianMs.toFixed(3)} | ${p.meanMs.toFixed(3)} | ${errorAt(profile, depthMm)} |`,
      );
    }
  }
  console.log('');
  console.log("The viewer's default path, the vertex shader (`shaderdeform.js`), on the same grid: the CPU");
  console.log('computes one radial table per update, whatever the mesh; the GPU bends every vertex each');
  console.log('draw. Draw times are whole frames of a 320 × 200 canvas on this WebGL implementation, bent');
  console.log('and at rest (their difference is what the bending costs the GPU):');
  console.log('');
  console.log('| profile | δ (mm) | reach (mm) | CPU per update median ms | draw bent ms | draw at rest ms |');
  console.log('|---|---:|---:|---:|---:|---:|');
  for (const profile of ['paper', 'fem']) {
    for (const depthMm of [1, 4, 8, 10]) {
      const depthM = depthMm / 1000;
      const g = await page.evaluate(timeGpuInPage, {
        profile,
        depthM,
        deformedRadiusM: Math.max(0, deformedRadius(depthM)),
        updates: UPDATES,
        draws: DRAWS,
      });
      if (g === null) continue;
      console.log(
        `| ${profile} | ${depthMm} | ${g.reachMm.toFixed(1)} | ${g.updateMs.toFixed(3)} | ${g.bentMs.toFixed(1)} | ${g.restMs.toFixed(1)} |`,
      );
    }
  }
  console.log('');
  console.log("The error column is the calibration report's (calibration/report/surface_<tool>.csv,");
  console.log("neo-Hookean FEM of the calibration block; the fem profile's with the depth's own row held");
  console.log('out, as a depth between rows draws it): the speed and the accuracy of each profile side by side.');
  console.log('The paper reports the computation time per step of its whole simulator on an Intel Core');
  console.log("i7-2600 at 3.4 GHz; these times are the viewer's deformation update alone, in JavaScript,");
  console.log('in Chromium on this host (the median is over batches of 10 updates, performance.now() is');
  console.log('coarsened to 0.1 ms in a page).');

  await page.evaluate(() => window.__softhaptic.animation(true));
  await page.waitForTimeout(1000);
  const start = await page.evaluate(() => ({ frames: window.__softhaptic.contactFrames(), at: performance.now() }));
  await page.waitForTimeout(LIVE_SECONDS * 1000);
  const end = await page.evaluate(() => ({ frames: window.__softhaptic.contactFrames(), at: performance.now() }));
  const receivedPerSecond = ((end.frames - start.frames) * 1000) / (end.at - start.at);
  const live = await page.evaluate(() => ({
    gpu: window.__softhaptic.gpu(),
    fps: window.__softhaptic.fps(),
    deform: window.__softhaptic.deformationTimings(),
    webgl: window.__softhaptic.webgl(),
    vertices: window.__softhaptic.vertexCount(),
  }));
  console.log('');
  console.log(
    `Live viewer after ${LIVE_SECONDS} s (headless Chromium, WebGL: ${live.webgl ? live.gpu.name : 'unavailable'}, ${live.vertices}-vertex mesh):`,
  );
  console.log(`  frame rate            ${live.fps.toFixed(1)} fps`);
  console.log(`  contact frames / s    ${receivedPerSecond.toFixed(1)} (server sends 50)`);
  console.log(
    `  deformation median    ${Number.isNaN(live.deform.medianMs) || live.deform.medianMs === null ? '—' : `${live.deform.medianMs.toFixed(3)} ms`} (${live.deform.samplesMs.length} frames in contact)`,
  );
} finally {
  await browser.close();
  await server.stop();
}
