// AudioWorklet: the microphone at the context's rate -> 16 kHz mono 16-bit PCM, posted to the
// page in 32 ms chunks (Whisper's input rate; openai/whisper audio.py SAMPLE_RATE). One chunk is
// one frame of the server's voice detector (Silero VAD: 512 samples at 16 kHz), so the end of
// speech is seen one frame after it is spoken, not up to a 100 ms chunk later.
//
// Downsampling averages the input samples that fall in each output sample's interval (a box
// filter): a cheap low-pass that keeps 44.1/48 kHz microphones from aliasing into speech band.

const OUT_RATE = 16000;
const CHUNK = 512; // 32 ms at 16 kHz

class PcmDownsampler extends AudioWorkletProcessor {
  constructor() {
    super();
    this.ratio = sampleRate / OUT_RATE; // `sampleRate` is a global of the worklet scope
    this.acc = 0;
    this.count = 0;
    this.pos = 0; // input samples consumed towards the next output sample
    this.out = new Int16Array(CHUNK);
    this.n = 0;
  }

  process(inputs) {
    const input = inputs[0];
    if (!input || input.length === 0) return true;
    const channels = input.length;
    const frames = input[0].length;
    for (let i = 0; i < frames; i += 1) {
      let v = 0;
      for (let c = 0; c < channels; c += 1) v += input[c][i];
      this.acc += v / channels;
      this.count += 1;
      this.pos += 1;
      if (this.pos >= this.ratio) {
        this.pos -= this.ratio;
        const s = Math.max(-1, Math.min(1, this.acc / this.count));
        this.out[this.n] = s < 0 ? s * 32768 : s * 32767;
        this.n += 1;
        this.acc = 0;
        this.count = 0;
        if (this.n === CHUNK) {
          this.port.postMessage(this.out.buffer, [this.out.buffer]);
          this.out = new Int16Array(CHUNK);
          this.n = 0;
        }
      }
    }
    return true;
  }
}

registerProcessor("pcm-downsampler", PcmDownsampler);
