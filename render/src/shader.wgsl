// futago's camera shaders: one vertex stage, a colour+depth fragment stage and a depth-only one.
//
// Depth leaves the GPU as the bits of an f32 in an R32Uint colour target: the optical-axis
// distance z of the surface in the camera frame, in metres (0 where nothing was drawn). Both
// wgpu's Vulkan and GL backends can render to and read back that format, which neither can do
// for depth textures or R32Float alike.

struct Camera {
    view_proj: mat4x4<f32>,
    view: mat4x4<f32>,
    // Unit vector towards the light (xyz, world frame) and the ambient share (w).
    light: vec4<f32>,
};

struct Model {
    model: mat4x4<f32>,
};

struct Material {
    // sRGB-encoded base colour, alpha unused.
    color: vec4<f32>,
};

@group(0) @binding(0) var<uniform> camera: Camera;
@group(0) @binding(1) var<uniform> model: Model;
@group(1) @binding(0) var<uniform> material: Material;
@group(1) @binding(1) var base_color: texture_2d<f32>;
@group(1) @binding(2) var base_sampler: sampler;

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) z: f32,
    @location(1) shade: f32,
    @location(2) uv: vec2<f32>,
};

@vertex
fn vs_main(
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) uv: vec2<f32>,
) -> VertexOut {
    let world = model.model * vec4<f32>(position, 1.0);
    var out: VertexOut;
    out.clip = camera.view_proj * world;
    out.z = (camera.view * world).z;
    // Two-sided Lambert under one fixed light plus ambient, per vertex (exact on flat faces):
    // view-independent shading. Colours and textures stay sRGB-encoded; with the 2.2 power
    // law, encode(albedo * shade) equals encoded albedo * shade^(1/2.2).
    let n = normalize((model.model * vec4<f32>(normal, 0.0)).xyz);
    let ambient = camera.light.w;
    out.shade = pow(ambient + (1.0 - ambient) * abs(dot(n, camera.light.xyz)), 1.0 / 2.2);
    out.uv = uv;
    return out;
}

struct ColorOut {
    @location(0) color: vec4<f32>,
    @location(1) depth: u32,
};

@fragment
fn fs_color(in: VertexOut) -> ColorOut {
    let texel = textureSample(base_color, base_sampler, in.uv);
    var out: ColorOut;
    out.color = vec4<f32>(material.color.rgb * texel.rgb * in.shade, 1.0);
    out.depth = bitcast<u32>(in.z);
    return out;
}

@fragment
fn fs_depth(in: VertexOut) -> @location(0) u32 {
    return bitcast<u32>(in.z);
}

// The z pre-pass: writes the z-buffer only.
@fragment
fn fs_none() {}
