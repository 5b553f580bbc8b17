// Dedicated worker: a steady 250 ms tick. Worker timers are not throttled like a hidden tab's own timers,
// so the dashboard notices a dropped connection and reconnects also in a background tab.
setInterval(() => postMessage(Date.now()), 250);
