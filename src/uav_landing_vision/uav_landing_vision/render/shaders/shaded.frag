#version 430
// Uniform albedo, Lambert + ambient, with the flat face normal from screen-space derivatives.
in vec3 v_cam;

uniform vec3 albedo;
uniform vec3 light_dir;  // towards the light, camera optical frame, unit
uniform float ambient;

out vec4 color;

void main() {
    vec3 n = normalize(cross(dFdx(v_cam), dFdy(v_cam)));
    if (dot(n, v_cam) > 0.0) {
        n = -n;
    }
    float lambert = max(dot(n, light_dir), 0.0);
    color = vec4(albedo * (ambient + (1.0 - ambient) * lambert), 1.0);
}
