// Figures of the live view's work (frames, redraws, samples, messages), read by the browser tests and the
// dashboard benchmark as window.__isorig.

export const metrics = {
  frames: 0, // requestAnimationFrame callbacks
  redraws: 0, // frames that redrew the plots
  drawMsTotal: 0,
  drawMsMax: 0,
  samples: 0, // samples received
  messages: 0,
  connects: 0,
  firstLiveFrameMs: null, // performance.now() at the first redraw showing live samples
  wsOpenMs: null,
  lastMessageMs: null,
  endCommandStdV: null, // after a test: the std of the valve command over its last second received (V)
};
window.__isorig = metrics;
