// Scene drawing: lit triangles (meshes) and unlit lines (ground grid), one vertex format.
// Hemisphere ambient plus one directional light; both faces lit (skirts are single-sided).

#bind scene: uniform SceneUniforms

struct VertexIn {
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) color: vec3<f32>,
}

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) normal: vec3<f32>,
    @location(1) color: vec3<f32>,
}

@vertex
fn vs_main(v: VertexIn) -> VertexOut {
    var out: VertexOut;
    out.clip = scene.view_proj * vec4<f32>(v.position, 1.0);
    out.normal = v.normal;
    out.color = v.color;
    return out;
}

@fragment
fn fs_lit(in: VertexOut, @builtin(front_facing) front: bool) -> @location(0) vec4<f32> {
    var n = normalize(in.normal);
    if !front {
        n = -n;
    }
    let diffuse = max(dot(n, scene.light_dir.xyz), 0.0);
    let ambient = mix(scene.ground_ambient.rgb, scene.sky_ambient.rgb, 0.5 * n.y + 0.5);
    return vec4<f32>(in.color * (ambient + diffuse * scene.light_dir.w), 1.0);
}

@fragment
fn fs_unlit(in: VertexOut) -> @location(0) vec4<f32> {
    return vec4<f32>(in.color, 1.0);
}
