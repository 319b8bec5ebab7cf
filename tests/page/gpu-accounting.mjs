// Counts the bytes of every GPU buffer a page creates, as held until the buffer or its
// device is destroyed: window.gpuLiveBytes(), window.gpuDevices(). A buffer left to
// the garbage collector counts as held, so the figure is an upper bound. Installed
// with page.addInitScript(gpuAccountingScript) by the page tests and the benchmarks.
export function gpuAccountingScript() {
  const devices = [];
  window.gpuLiveBytes = () => devices.filter((d) => !d.destroyed)
    .reduce((n, d) => n + [...d.buffers.values()].reduce((a, b) => a + b, 0), 0);
  window.gpuDevices = () => devices.filter((d) => !d.destroyed).length;
  const request = GPUAdapter.prototype.requestDevice;
  GPUAdapter.prototype.requestDevice = async function (...args) {
    const device = await request.apply(this, args);
    const rec = { buffers: new Map(), destroyed: false };
    devices.push(rec);
    device.accounting = rec;
    return device;
  };
  const create = GPUDevice.prototype.createBuffer;
  GPUDevice.prototype.createBuffer = function (desc) {
    const b = create.call(this, desc);
    this.accounting?.buffers.set(b, Number(desc.size));
    b.accounting = this.accounting;
    return b;
  };
  const destroyBuffer = GPUBuffer.prototype.destroy;
  GPUBuffer.prototype.destroy = function () {
    this.accounting?.buffers.delete(this);
    return destroyBuffer.call(this);
  };
  const destroyDevice = GPUDevice.prototype.destroy;
  GPUDevice.prototype.destroy = function () {
    if (this.accounting) this.accounting.destroyed = true;
    return destroyDevice.call(this);
  };
}
