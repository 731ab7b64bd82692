// The binary mesh frames the browser pages receive (common/web/browser_frames.h):
// a 32-byte little-endian header (u8 kind, u8 version, u16 reserved, u32 V,
// u32 F, u32 O, f64 sim_time, f64 seq), then for a surface snapshot (kind 1)
// f32 positions[3V] and u32 triangles[3F], the last O of them opened by a
// cut, and for a positions update (kind 2) f32 positions[3V]. Shared by the
// observer and the trainee pages.

export const HEADER_BYTES = 32;
export const KIND_SNAPSHOT = 1;
export const KIND_POSITIONS = 2;
export const FRAME_VERSION = 1;

const littleEndianHost = new Uint8Array(new Uint16Array([1]).buffer)[0] === 1;

/** `count` little-endian 32-bit values at `offset` as a fresh typed array. */
function readArray32(buffer, offset, count, ArrayType) {
  if (littleEndianHost) return new ArrayType(buffer.slice(offset, offset + 4 * count));
  const view = new DataView(buffer, offset, 4 * count);
  const out = new ArrayType(count);
  const get = ArrayType === Float32Array ? (i) => view.getFloat32(4 * i, true)
                                         : (i) => view.getUint32(4 * i, true);
  for (let i = 0; i < count; ++i) out[i] = get(i);
  return out;
}

/**
 * Decodes one binary frame. Returns {kind, V, F, O, simTime, seq, positions,
 * triangles (null in an update)}, or a string saying why it is malformed.
 */
export function parseMeshFrame(buffer) {
  if (buffer.byteLength < HEADER_BYTES) return `binary frame of ${buffer.byteLength} bytes is shorter than its header`;
  const h = new DataView(buffer, 0, HEADER_BYTES);
  const kind = h.getUint8(0);
  const version = h.getUint8(1);
  const V = h.getUint32(4, true);
  const F = h.getUint32(8, true);
  const O = h.getUint32(12, true);
  const simTime = h.getFloat64(16, true);
  const seq = h.getFloat64(24, true);
  if (version !== FRAME_VERSION) return `binary frame version ${version}, expected ${FRAME_VERSION}`;
  if (!Number.isFinite(seq) || !Number.isFinite(simTime)) return 'binary frame with a non-finite seq or sim_time';
  if (kind === KIND_SNAPSHOT) {
    const expected = HEADER_BYTES + 12 * V + 12 * F;
    if (buffer.byteLength !== expected) return `snapshot of ${buffer.byteLength} bytes, expected ${expected} for V=${V} F=${F}`;
    if (O > F) return `snapshot with ${O} opened of ${F} triangles`;
    const triangles = readArray32(buffer, HEADER_BYTES + 12 * V, 3 * F, Uint32Array);
    for (let i = 0; i < triangles.length; ++i) {
      if (triangles[i] >= V) return `snapshot triangle index ${triangles[i]} out of range (V=${V})`;
    }
    const positions = readArray32(buffer, HEADER_BYTES, 3 * V, Float32Array);
    return { kind, V, F, O, simTime, seq, positions, triangles };
  }
  if (kind === KIND_POSITIONS) {
    const expected = HEADER_BYTES + 12 * V;
    if (buffer.byteLength !== expected) return `positions update of ${buffer.byteLength} bytes, expected ${expected} for V=${V}`;
    if (F !== 0 || O !== 0) return `positions update with F=${F} O=${O}, expected 0`;
    const positions = readArray32(buffer, HEADER_BYTES, 3 * V, Float32Array);
    return { kind, V, F, O, simTime, seq, positions, triangles: null };
  }
  return `binary frame of unknown kind ${kind}`;
}
