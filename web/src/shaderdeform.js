// The GPU path of the deformation: the vertex shader of each render mesh's material bends its
// vertices, so an update costs the CPU one radial table of the profile (4 097 samples, the
// same `surfaceTable` the CPU path reads, or `profileTable` for the paper's Bézier) and a few
// uniforms, whatever the mesh's size, and no vertex buffer is uploaded again. The shader does
// per vertex what `MeshDeformer.#move` does (deformer.js): the vertex's radial distance r from
// the contact axis, the table's z and u at r (linear between samples), the vertex moved by
// −z·n + u·e_r, and the normal ∝ (1 + u′)·n_rest + z′·e_r. `MeshDeformer` stays the reference:
// it runs where WebGL does not, and the test hooks evaluate with it what the shader draws.
import * as THREE from 'three';

import { SURFACE_TABLE_INTERVALS } from './deformation.js';

const SHADER_PARS = /* glsl */ `
uniform highp sampler2D shTable;
uniform vec3 shPoint;
uniform vec3 shNormal;
uniform float shReach;
uniform float shSamplesPerM;
uniform float shDepressionScale;
uniform vec3 shDepressionColor;
`;

// Runs before the normal and the position are read (three.js's chunks `beginnormal_vertex` and
// `begin_vertex` come after `color_vertex`), so it also tints the depression map's colour.
const SHADER_DEFORM = /* glsl */ `
vec3 shDisplacement = vec3(0.0);
vec3 shObjectNormal = normal;
if (shReach > 0.0) {
  vec3 shV = position - shPoint;
  float shAxial = dot(shV, shNormal);
  vec3 shE = shV - shAxial * shNormal;
  float shR = length(shE);
  if (abs(shAxial) < shReach && shR < shReach) {
    float shX = shR * shSamplesPerM;
    int shK = min(int(shX), ${SURFACE_TABLE_INTERVALS - 1});
    float shF = shX - float(shK);
    vec2 shS0 = texelFetch(shTable, ivec2(shK, 0), 0).rg;
    vec2 shS1 = texelFetch(shTable, ivec2(shK + 1, 0), 0).rg;
    vec2 shZu = shS0 + shF * (shS1 - shS0);
    vec2 shSlope = (shS1 - shS0) * shSamplesPerM;
    float shInvR = shR > 0.0 ? 1.0 / shR : 0.0;
    shDisplacement = shE * (shZu.y * shInvR) - shNormal * shZu.x;
    shObjectNormal = normal * (1.0 + shSlope.y) + shE * (shSlope.x * shInvR);
  }
}
#ifdef USE_COLOR
if (shDepressionScale > 0.0) {
  float shT = min(length(shDisplacement) / shDepressionScale, 1.0);
  vColor.rgb *= vec3(1.0) - shT * (vec3(1.0) - shDepressionColor);
}
#endif
`;

/**
 * The radial table as a texture (one row of N + 1 texels, z in red and u in green, metres),
 * shared by every mesh's material; `update` copies a table into it.
 */
export class DeformationTable {
  constructor() {
    this.data = new Float32Array(2 * (SURFACE_TABLE_INTERVALS + 1));
    this.texture = new THREE.DataTexture(this.data, SURFACE_TABLE_INTERVALS + 1, 1, THREE.RGFormat, THREE.FloatType);
    // Read with texelFetch, interpolated by the shader: no filtering, no mipmaps.
    this.texture.minFilter = THREE.NearestFilter;
    this.texture.magFilter = THREE.NearestFilter;
    this.texture.generateMipmaps = false;
    this.texture.needsUpdate = true;
    this.reachM = 0;
    this.samplesPerM = 0;
  }

  /** Loads a table from `surfaceTable` or `profileTable` (`{z, u, reachM, samplesPerM}`). */
  update(table) {
    const data = this.data;
    const z = table.z;
    const u = table.u;
    for (let k = 0; k <= SURFACE_TABLE_INTERVALS; k++) {
      data[2 * k] = z[k];
      data[2 * k + 1] = u[k];
    }
    this.reachM = table.reachM;
    this.samplesPerM = table.samplesPerM;
    this.texture.needsUpdate = true;
  }

  /**
   * Makes `material` (a three.js built-in lit material) bend its mesh with this table; returns
   * the mesh's own uniforms (`point`, `normal` in its object frame, `reachM`; 0 draws the rest
   * shape) to set each frame with `place`.
   */
  install(material, depressionColor) {
    const uniforms = {
      shTable: { value: this.texture },
      shPoint: { value: new THREE.Vector3() },
      shNormal: { value: new THREE.Vector3(0, 1, 0) },
      shReach: { value: 0 },
      shSamplesPerM: { value: 0 },
      shDepressionScale: { value: 0 },
      shDepressionColor: { value: new THREE.Vector3(...depressionColor) },
    };
    material.onBeforeCompile = (shader) => {
      Object.assign(shader.uniforms, uniforms);
      shader.vertexShader = shader.vertexShader
        .replace('#include <common>', `#include <common>\n${SHADER_PARS}`)
        .replace('#include <color_vertex>', `#include <color_vertex>\n${SHADER_DEFORM}`)
        .replace('#include <beginnormal_vertex>', 'vec3 objectNormal = shObjectNormal;')
        .replace('#include <begin_vertex>', '#include <begin_vertex>\ntransformed += shDisplacement;');
    };
    material.customProgramCacheKey = () => 'softhaptic-deformation';
    return uniforms;
  }

  /**
   * Sets one mesh's uniforms for this frame: the contact point and unit normal in its object
   * frame when `on`, else nothing moves; `depressionScaleM` > 0 tints the depression map.
   */
  place(uniforms, on, point, normal, depressionScaleM) {
    uniforms.shReach.value = on ? this.reachM : 0;
    uniforms.shSamplesPerM.value = this.samplesPerM;
    uniforms.shPoint.value.set(point[0], point[1], point[2]);
    uniforms.shNormal.value.set(normal[0], normal[1], normal[2]).normalize();
    uniforms.shDepressionScale.value = depressionScaleM;
  }
}
