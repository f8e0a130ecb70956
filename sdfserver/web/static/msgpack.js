// A small MessagePack codec: nil, booleans, numbers, strings, binary, arrays and maps.
// Binary values decode to Uint8Array; integers beyond 2^53 decode to Number (lossy).

const textEncoder = new TextEncoder();
const textDecoder = new TextDecoder();

export function encode(value) {
  const out = [];
  const push8 = (b) => out.push(b & 0xff);
  const pushN = (v, bytes) => { for (let i = bytes - 1; i >= 0; i--) push8(Math.floor(v / 2 ** (8 * i))); };
  const pushBytes = (bytes) => { for (const b of bytes) out.push(b); };
  const write = (v) => {
    if (v === null || v === undefined) push8(0xc0);
    else if (v === false) push8(0xc2);
    else if (v === true) push8(0xc3);
    else if (typeof v === "number") {
      if (Number.isInteger(v) && v >= 0 && v < 2 ** 32) {
        if (v < 128) push8(v);
        else if (v < 256) { push8(0xcc); push8(v); }
        else if (v < 65536) { push8(0xcd); pushN(v, 2); }
        else { push8(0xce); pushN(v, 4); }
      } else if (Number.isInteger(v) && v < 0 && v >= -(2 ** 31)) {
        if (v >= -32) push8(v);
        else { push8(0xd2); const b = new DataView(new ArrayBuffer(4)); b.setInt32(0, v); pushBytes(new Uint8Array(b.buffer)); }
      } else {
        push8(0xcb); const b = new DataView(new ArrayBuffer(8)); b.setFloat64(0, v); pushBytes(new Uint8Array(b.buffer));
      }
    } else if (typeof v === "string") {
      const bytes = textEncoder.encode(v);
      if (bytes.length < 32) push8(0xa0 | bytes.length);
      else if (bytes.length < 256) { push8(0xd9); push8(bytes.length); }
      else if (bytes.length < 65536) { push8(0xda); pushN(bytes.length, 2); }
      else { push8(0xdb); pushN(bytes.length, 4); }
      pushBytes(bytes);
    } else if (v instanceof Uint8Array) {
      if (v.length < 256) { push8(0xc4); push8(v.length); }
      else if (v.length < 65536) { push8(0xc5); pushN(v.length, 2); }
      else { push8(0xc6); pushN(v.length, 4); }
      pushBytes(v);
    } else if (Array.isArray(v)) {
      if (v.length < 16) push8(0x90 | v.length);
      else if (v.length < 65536) { push8(0xdc); pushN(v.length, 2); }
      else { push8(0xdd); pushN(v.length, 4); }
      v.forEach(write);
    } else if (typeof v === "object") {
      const keys = Object.keys(v).filter((k) => v[k] !== undefined);
      if (keys.length < 16) push8(0x80 | keys.length);
      else { push8(0xde); pushN(keys.length, 2); }
      for (const k of keys) { write(k); write(v[k]); }
    } else throw new TypeError(`cannot encode ${typeof v}`);
  };
  write(value);
  return new Uint8Array(out);
}

export function decode(buffer) {
  const bytes = buffer instanceof Uint8Array ? buffer : new Uint8Array(buffer);
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  let pos = 0;
  const u = (n) => { let v = 0; for (let i = 0; i < n; i++) v = v * 256 + bytes[pos++]; return v; };
  const str = (n) => { const s = textDecoder.decode(bytes.subarray(pos, pos + n)); pos += n; return s; };
  const bin = (n) => { const b = bytes.slice(pos, pos + n); pos += n; return b; };
  const arr = (n) => { const a = new Array(n); for (let i = 0; i < n; i++) a[i] = read(); return a; };
  const map = (n) => { const m = {}; for (let i = 0; i < n; i++) { const k = read(); m[k] = read(); } return m; };
  const signed = (n) => { const v = n === 1 ? view.getInt8(pos) : n === 2 ? view.getInt16(pos) : n === 4 ? view.getInt32(pos) : Number(view.getBigInt64(pos)); pos += n; return v; };
  const read = () => {
    const t = bytes[pos++];
    if (t < 0x80) return t;
    if (t < 0x90) return map(t & 0x0f);
    if (t < 0xa0) return arr(t & 0x0f);
    if (t < 0xc0) return str(t & 0x1f);
    if (t >= 0xe0) return t - 256;
    switch (t) {
      case 0xc0: return null;
      case 0xc2: return false;
      case 0xc3: return true;
      case 0xc4: return bin(u(1));
      case 0xc5: return bin(u(2));
      case 0xc6: return bin(u(4));
      case 0xca: { const v = view.getFloat32(pos); pos += 4; return v; }
      case 0xcb: { const v = view.getFloat64(pos); pos += 8; return v; }
      case 0xcc: return u(1);
      case 0xcd: return u(2);
      case 0xce: return u(4);
      case 0xcf: return u(8);
      case 0xd0: return signed(1);
      case 0xd1: return signed(2);
      case 0xd2: return signed(4);
      case 0xd3: return signed(8);
      case 0xd9: return str(u(1));
      case 0xda: return str(u(2));
      case 0xdb: return str(u(4));
      case 0xdc: return arr(u(2));
      case 0xdd: return arr(u(4));
      case 0xde: return map(u(2));
      case 0xdf: return map(u(4));
      case 0xd4: pos += 2; return null;
      case 0xd5: pos += 3; return null;
      case 0xd6: pos += 5; return null;
      case 0xd7: pos += 9; return null;
      case 0xd8: pos += 17; return null;
      case 0xc7: { const n = u(1); pos += 1 + n; return null; }
      case 0xc8: { const n = u(2); pos += 1 + n; return null; }
      case 0xc9: { const n = u(4); pos += 1 + n; return null; }
      default: throw new Error(`bad msgpack byte 0x${t.toString(16)}`);
    }
  };
  return read();
}
