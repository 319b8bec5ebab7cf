// The map canvas through WebGPU: each layer is a texture drawn as one quad with the
// view's pan, zoom and the layer's opacity, blended in order. Returns null when the
// browser cannot give a WebGPU canvas; the caller then draws with a 2D canvas.
const WGSL = `
struct U { canvas: vec2f, tex: vec2f, offset: vec2f, scale: f32, opacity: f32 }
@group(0) @binding(0) var<uniform> u: U;
@group(0) @binding(1) var t: texture_2d<f32>;
@group(0) @binding(2) var s: sampler;
struct VO { @builtin(position) p: vec4f, @location(0) uv: vec2f }
@vertex fn vs(@builtin(vertex_index) i: u32) -> VO {
  let c = vec2f(f32(i & 1u), f32(i >> 1u));
  let px = u.offset + c * u.tex * u.scale;
  return VO(vec4f(px.x / u.canvas.x * 2.0 - 1.0, 1.0 - px.y / u.canvas.y * 2.0, 0.0, 1.0), c);
}
@fragment fn fs(v: VO) -> @location(0) vec4f {
  let c = textureSample(t, s, v.uv);
  return vec4f(c.rgb, c.a * u.opacity);
}`;

export async function createGpuView(canvas) {
  if (!navigator.gpu) return null;
  const adapter = await navigator.gpu.requestAdapter();
  if (!adapter) return null;
  const device = await adapter.requestDevice();
  const ctx = canvas.getContext('webgpu');
  if (!ctx) return null;
  const format = navigator.gpu.getPreferredCanvasFormat();
  ctx.configure({ device, format, alphaMode: 'opaque' });
  const module = device.createShaderModule({ code: WGSL });
  const blend = { srcFactor: 'src-alpha', dstFactor: 'one-minus-src-alpha', operation: 'add' };
  const pipeline = device.createRenderPipeline({
    layout: 'auto',
    vertex: { module, entryPoint: 'vs' },
    fragment: { module, entryPoint: 'fs', targets: [{ format, blend: { color: blend, alpha: blend } }] },
    primitive: { topology: 'triangle-strip' },
  });
  const sampler = device.createSampler({ magFilter: 'nearest', minFilter: 'linear' });
  const textures = new Map();
  // One uniform buffer per layer, written before each draw: a buffer made per draw
  // would stay on the GPU until the garbage collector found it (one per frame).
  const uniforms = new Map();
  const uniformOf = (name) => {
    if (!uniforms.has(name)) uniforms.set(name, device.createBuffer({ size: 32, usage: GPUBufferUsage.UNIFORM | GPUBufferUsage.COPY_DST }));
    return uniforms.get(name);
  };
  return {
    kind: 'webgpu',
    // Uploads a layer from a (2D) canvas of the map's size.
    setLayer(name, source) {
      let t = textures.get(name);
      if (!t || t.width !== source.width || t.height !== source.height) {
        t?.destroy();
        t = device.createTexture({
          size: [source.width, source.height],
          format: 'rgba8unorm',
          usage: GPUTextureUsage.TEXTURE_BINDING | GPUTextureUsage.COPY_DST | GPUTextureUsage.RENDER_ATTACHMENT,
        });
        textures.set(name, t);
      }
      device.queue.copyExternalImageToTexture({ source }, { texture: t }, [source.width, source.height]);
    },
    // Draws the visible layers (in order) with the view transform.
    draw(order, layers, view) {
      const enc = device.createCommandEncoder();
      const pass = enc.beginRenderPass({
        colorAttachments: [{ view: ctx.getCurrentTexture().createView(), loadOp: 'clear', storeOp: 'store', clearValue: { r: 0.07, g: 0.07, b: 0.07, a: 1 } }],
      });
      pass.setPipeline(pipeline);
      for (const name of order) {
        const l = layers[name];
        const t = textures.get(name);
        if (!l || !l.visible || !t) continue;
        const u = uniformOf(name);
        device.queue.writeBuffer(u, 0, new Float32Array([canvas.width, canvas.height, t.width, t.height, view.x, view.y, view.scale, l.opacity]));
        pass.setBindGroup(0, device.createBindGroup({
          layout: pipeline.getBindGroupLayout(0),
          entries: [{ binding: 0, resource: { buffer: u } }, { binding: 1, resource: t.createView() }, { binding: 2, resource: sampler }],
        }));
        pass.draw(4);
      }
      pass.end();
      device.queue.submit([enc.finish()]);
    },
  };
}
