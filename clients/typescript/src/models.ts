/**
 * What the client sends and returns. Positions and sizes are `[x, y, z]`; arrays are flat typed
 * arrays in the server's layout, C-ordered `(z, y, x)`, with their `shape` beside them.
 */

import type { Dtype, TypedArray } from "./wire.js";

export type Vec3 = [number, number, number];
/** A half-open box of voxels, `[min, max]` (`min <= p < max`). */
export type Box = [Vec3, Vec3];

export type Algorithm = "exact" | "brute" | "fim" | "jfa" | "jfa+1" | "jfa+2" | "jfa_fim" | "conservative";

/** The box of chunks computed with the world's `algorithm` (the rest uses `lodAlgorithm`). */
export interface Focus {
  center: Vec3;
  size: Vec3;
}

/** A generated terrain for a sparse world; all but `kind` optional (docs/api.md, "Worlds"). */
export interface Generate {
  kind: "terrain";
  seed?: number;
  base?: number;
  amplitude?: number;
  overhang?: number;
  cave_depth?: number;
}

/** Every creation option of `POST /v1/worlds` but `size`; left out: the server's default. */
export interface WorldOptions {
  chunkSize?: number;
  maxDistance?: number;
  algorithm?: Algorithm;
  lodAlgorithm?: Algorithm;
  focus?: Focus | null;
  borders?: "exact" | "padded";
  storage?: "dense" | "sparse";
  generate?: Generate | null;
  metric?: "manhattan" | "euclidean";
  signed?: boolean;
  /** World units per voxel. */
  voxelSize?: number;
  /** The world-unit position of voxel (0, 0, 0)'s low corner. */
  origin?: Vec3;
  /** 255 `[r, g, b]` colours: value `v` is drawn as `palette[v - 1]`; null: RGB332. */
  palette?: Vec3[] | null;
}

/** What `PATCH /v1/worlds/{id}` changes; a setting left out stays as it is, `focus: null` removes it. */
export type WorldUpdate = Omit<WorldOptions, "chunkSize" | "storage" | "generate">;

/** A world's description as the server gives it (`raw`: every field, as sent). */
export interface WorldInfo {
  id: string;
  size: Vec3;
  chunkSize: number;
  maxDistance: number;
  algorithm: string;
  lodAlgorithm: string;
  borders: string;
  storage: string;
  generate: Generate | null;
  metric: string;
  signed: boolean;
  voxelSize: number;
  origin: Vec3;
  palette: Vec3[] | null;
  focus: Focus | null;
  version: number;
  fieldVersion: number;
  dirtyChunks: number;
  lastRecomputeMs: number | null;
  deviceBytes: number;
  owner: string | null;
  /** What the server says beside the world: an import's sparse world costing more than a dense one. */
  warnings: string[];
  raw: Record<string, unknown>;
}

/** A box of the field or the voxels. */
export interface Block {
  /** `[x, y, z]` of the first value. */
  origin: Vec3;
  /** `[nz, ny, nx]`. */
  shape: Vec3;
  /** The answer's dtype, which decides `data`'s type: uint8, uint16 (packed), int16 (signed
   * Manhattan) or float32 (Euclidean); voxels are uint8. */
  dtype: Dtype;
  data: TypedArray;
  /** The edit version this block reflects. */
  version: number;
  format: "distance" | "packed" | "voxels";
  /** `distance`, `distance_colour`, `squared_distance` (packed) or `voxels`. */
  content: string;
}

/** The field at points (world units). */
export interface QueryResult {
  /** (N) world units, interpolated; negative inside solids of a signed world. */
  distances: Float32Array;
  /** (N * 3) x y z, d(distance)/d(world unit), not normalised. */
  gradients: Float32Array;
  /** (N) the value of the voxel holding each point, 0 in air. */
  colours: Uint8Array;
  version: number;
}

/** Spheres against the field. */
export interface SphereResult {
  /** (N) the distance at the centre minus the radius (negative: overlapping a solid). */
  clearances: Float32Array;
  /** (N * 3) unit vectors out of collision; zero where the field is flat. */
  directions: Float32Array;
  version: number;
}

/** Each ray's first solid voxel within its max length. */
export interface RayResult {
  /** (N) 1 for a hit, 0 for a miss. */
  hits: Uint8Array;
  /** (N) world units along the normalised direction (a miss: its max length). */
  distances: Float32Array;
  /** (N * 3) the entered face's normal (zero: a miss, or a ray starting in a solid). */
  normals: Float32Array;
  /** (N) the voxel value hit (0: a miss). */
  colours: Uint8Array;
  /** (N * 3) the voxel hit (-1s: a miss). */
  voxels: Int32Array;
  version: number;
}

/**
 * A view for `render`, `pick` and the stream, in voxel units, y up: either `target` (look at
 * that point) or `yawDeg`/`pitchDeg` (0, 0 looks along -z; yaw turns toward +x).
 */
export interface Camera {
  position: Vec3;
  target?: Vec3;
  yawDeg?: number;
  pitchDeg?: number;
  fovYDeg?: number;
  width?: number;
  height?: number;
}

/** The renderer's options (docs/rendering.md), in the wire's names. */
export interface RenderOptions {
  ambient_occlusion?: boolean;
  shadows?: boolean;
  sky_rgb?: Vec3;
  light?: Vec3;
  highlight?: Vec3;
  highlight_radius?: number;
  cursor?: Vec3;
}

export type FrameFormat = "png" | "jpeg" | "rgba";

/** A rendered image. */
export interface Frame {
  format: FrameFormat;
  /** The encoded image; for rgba, height * width * 4 bytes, rows top first. */
  data: Uint8Array;
  fieldVersion: number;
  width: number;
  height: number;
  /** The kernel's device time, when the server says. */
  renderMs: number | null;
}

/** The voxel under a pixel, its face normal, and where a placed voxel would go. */
export interface Pick {
  voxel: Vec3;
  normal: Vec3;
  place: Vec3;
  fieldVersion: number;
}

export type FileFormat = "snapshot" | "npy" | "vox";

/** A world as a file (`GET .../export`). */
export interface Exported {
  format: FileFormat;
  /** The edit version the file holds. */
  version: number;
  data: Uint8Array;
  /** The server's suggestion, e.g. "<id>.npy". */
  filename: string;
}

/** One changed chunk from the stream. */
export interface ChunkUpdate {
  chunk: Vec3;
  origin: Vec3;
  /** `[cs, cs, cs]`, z y x. */
  shape: number[];
  dtype: Dtype;
  data: TypedArray;
}

/** A frame from the stream: `ack`, `subscribed`, `chunks`, `frame`, `pong`, ... (`raw`: as sent). */
export interface StreamMessage {
  type: string;
  id: number | null;
  version: number | null;
  /** A `chunks` message's chunks (empty otherwise). */
  chunks: ChunkUpdate[];
  raw: Record<string, unknown>;
}
