// Video frames: the stream's H.264, VP9 or AV1 chunks decoded by WebCodecs' VideoDecoder and drawn
// on the canvas. A "video" message starts each stream (codec string, size, encoder); every "frame"
// after it is one chunk (H.264 as Annex B, so the decoder is configured without a description).
// Chunks depend on the ones before them: all are decoded, in order, and a decoder that fails or
// falls behind waits for a keyframe, which it asks the server for.

export const VIDEO_FORMATS = ["h264", "vp9", "av1"];
const PROBE_CODECS = { h264: "avc1.42E01F", vp9: "vp09.00.31.08", av1: "av01.0.05M.08" };
// Chunks queued in the decoder beyond which it has fallen behind (a hidden tab, a slow machine):
// it skips to the next keyframe rather than show a picture that lags ever further.
const MAX_DECODE_QUEUE = 4;

// Whether this browser decodes `format` with WebCodecs (Chromium does; some browsers lack it).
export async function canDecode(format) {
  if (typeof VideoDecoder === "undefined" || !(format in PROBE_CODECS)) return false;
  try {
    const { supported } = await VideoDecoder.isConfigSupported({ codec: PROBE_CODECS[format], optimizeForLatency: true });
    return supported === true;
  } catch {
    return false;
  }
}

export class VideoPlayer {
  // draw(videoFrame): paints one decoded picture; askKeyframe(): sends {type: "keyframe"}.
  constructor(draw, askKeyframe) {
    this.draw = draw;
    this.askKeyframe = askKeyframe;
    this.decoder = null;
    this.config = null;
    this.waitingForKey = true;
    this.stats = { codec: null, encoder: null, hardware: false, decoded: 0, keyframes: 0, skipped: 0,
      errors: [], width: 0, height: 0 };
  }

  // A "video" message: a new stream, a new decoder.
  start(message) {
    this.config = { codec: message.codec, codedWidth: message.width, codedHeight: message.height,
      optimizeForLatency: true };
    Object.assign(this.stats, { codec: message.codec, encoder: message.encoder, hardware: message.hardware,
      width: message.width, height: message.height });
    this.open();
  }

  open() {
    this.close();
    this.decoder = new VideoDecoder({
      output: (frame) => {
        this.stats.decoded++;
        try { this.draw(frame); } finally { frame.close(); }
      },
      error: (err) => {  // the decoder is closed now: a new one waits for a keyframe
        this.stats.errors.push(String(err));
        this.decoder = null;
        this.recover();
      },
    });
    this.decoder.configure(this.config);
    this.waitingForKey = true;
  }

  recover() {
    this.waitingForKey = true;
    this.askKeyframe();
  }

  // A "frame" message of a video format.
  decode(message) {
    if (!this.config) return;  // no stream started yet (a frame of one that ended)
    if (!this.decoder) this.open();
    if (!message.key && (this.waitingForKey || this.decoder.decodeQueueSize >= MAX_DECODE_QUEUE)) {
      this.stats.skipped++;
      if (!this.waitingForKey) this.recover();
      return;
    }
    this.waitingForKey = false;
    if (message.key) this.stats.keyframes++;
    this.decoder.decode(new EncodedVideoChunk({ type: message.key ? "key" : "delta", timestamp: message.timestamp,
      data: message.data }));
  }

  close() {
    if (this.decoder && this.decoder.state !== "closed") this.decoder.close();
    this.decoder = null;
  }
}
