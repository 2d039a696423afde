// The WebSocket to the node: binary frames in (a JSON header, then typed-array views on the same
// buffer: no copy, no parsing library), JSON text out. Reconnects on its own.

const TYPED = { f4: Float32Array, u4: Uint32Array, i4: Int32Array, u2: Uint16Array, u1: Uint8Array };
const decoder = new TextDecoder();

export function decodeFrame(buffer) {
  const length = new DataView(buffer).getUint32(0, true);
  const header = JSON.parse(decoder.decode(new Uint8Array(buffer, 4, length)));
  const arrays = {};
  for (const [name, [dtype, shape, offset]] of Object.entries(header.arrays)) {
    const count = shape.reduce((a, b) => a * b, 1);
    arrays[name] = new TYPED[dtype](buffer, offset, count);
  }
  return { header, arrays };
}

// The link's token was exchanged for a cookie when the page loaded: out of the address bar, so it
// stays out of the browser's history, bookmarks and what is shared of this page.
export function forgetToken() {
  const url = new URL(location.href);
  if (!url.searchParams.has('token')) return;
  url.searchParams.delete('token');
  history.replaceState(history.state, '', url);
}

export class Link {
  // onFrame({header, arrays}) for every frame; onState(connected) when the socket opens or closes.
  constructor(onFrame, onState) {
    this.onFrame = onFrame;
    this.onState = onState;
    this.ws = null;
    this.retry = 250;
    this.received = 0;
    this.closed = false;
    this.connect();
  }

  connect() {
    const scheme = location.protocol === 'https:' ? 'wss' : 'ws';
    const ws = (this.ws = new WebSocket(`${scheme}://${location.host}/ws`));   // the cookie says who
    ws.binaryType = 'arraybuffer';
    ws.onopen = () => { this.retry = 250; this.onState(true); };
    ws.onmessage = (event) => {
      if (typeof event.data === 'string') return;
      this.received++;
      this.onFrame(decodeFrame(event.data));
    };
    ws.onclose = () => {
      this.onState(false);
      if (this.closed) return;
      setTimeout(() => this.connect(), this.retry);
      this.retry = Math.min(this.retry * 2, 4000);
    };
  }

  // For good (the page is going away): no reconnection.
  close() {
    this.closed = true;
    if (this.ws) this.ws.close();
  }

  get open() { return this.ws !== null && this.ws.readyState === WebSocket.OPEN; }

  send(message) {
    if (this.open) this.ws.send(JSON.stringify(message));
  }
}
