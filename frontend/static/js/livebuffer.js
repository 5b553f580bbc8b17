// The live view's samples: typed-array buffers of the recent samples in display units (compacted when full), the
// per-cycle extremes the readouts keep, and the statuses of a test that has ended.

import { lowerBound } from "./plots.js";

export const CAP = 131072; // samples kept before the buffer is compacted
const KEEP = 65536; // samples kept on compaction

// Buffer channels, in display units: time (s), target/model/displacement and errors (length), voltage (V),
// force, load pressure, adapted parameters (their declared unit; a length in the length unit).
export const CH = ["t", "r", "ym", "y", "v", "f", "pl", "ar", "ay", "as", "e_ym", "e_r"];
export const QUANTITY = { r: "length", ym: "length", y: "length", e_ym: "length", e_r: "length", f: "force", pl: "pressure" };

// How a test ended: any of these (BAD: not as planned)
export const FINAL = new Set(["completed", "stopped", "aborted", "interrupted", "failed"]);
export const BAD = new Set(["aborted", "interrupted", "failed"]);

export class Buffer {
  constructor() {
    this.a = {};
    for (const c of CH) this.a[c] = new Float64Array(CAP);
    this.len = 0;
  }

  clear() {
    this.len = 0;
  }

  /** Make room: drop the oldest samples, returns how many were dropped. */
  compact() {
    const drop = this.len - KEEP;
    for (const c of CH) this.a[c].copyWithin(0, drop, this.len);
    this.len = KEEP;
    return drop;
  }

  scale(channel, factor) {
    const x = this.a[channel];
    for (let i = 0; i < this.len; i++) x[i] *= factor;
  }

  /** Index of the first sample with t >= time (binary search). */
  lowerBound(time) {
    return lowerBound(this.a.t, this.len, time);
  }
}

/** The extremes of a cycle, scanned incrementally from buffer index `start`. */
export function emptyExtremes(start) {
  return { start, scanned: start, yMax: -Infinity, yMin: Infinity, fMax: -Infinity, fMin: Infinity,
    vMax: -Infinity, vMin: Infinity, eAbs: 0, plAbs: 0, yAbs: 0, fAbs: 0, velAbs: 0 };
}
