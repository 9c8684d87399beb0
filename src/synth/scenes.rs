//! Ray-traced scenes with known intrinsic layers, richer than [`super::generate`]: spheres with
//! curved Lambertian shading on a floor before a wall, cast shadows that cross several surfaces,
//! coloured illuminants and sky light, additive specular highlights in the illuminant's colour,
//! striped and textured albedo. They are what `covec eval --intrinsic` measures.
//!
//! The image model is covec's: `image = clamp01(albedo · shade + light)` in sRGB values, with
//! `shade` an RGB product of illuminant colour and geometry (≤ 1), and `light` the specular
//! term. Each pixel averages 2 × 2 samples, so edges are anti-aliased in every layer.

use crate::render::Image;

/// A generated scene and its true layers, all `size × size`.
#[derive(Clone, Debug)]
pub struct LitScene {
    /// `clamp01(albedo · shade + light)`.
    pub image: Image,
    /// Surface colours.
    pub albedo: Image,
    /// Illumination reaching the surface (illuminant colour × geometry × visibility).
    pub shade: Image,
    /// Additive specular highlights.
    pub light: Image,
    /// Pixels where a surface facing the main light is shadowed from it by another object.
    pub cast_shadow: Vec<bool>,
    /// The object seen at each pixel (most of its samples): 0 floor, 1 wall, 2 + k sphere k.
    pub objects: Vec<u8>,
    /// The image with the albedo of the first sphere replaced by [`EDIT_COLOUR`] (or
    /// [`EDIT_COLOUR_ALT`] when the sphere is already bluish), lighting unchanged: the true
    /// result of a recolour.
    pub edited: Image,
}

/// New albedo of the edited sphere.
pub const EDIT_COLOUR: [f32; 3] = [0.2, 0.45, 0.85];
/// New albedo of the edited sphere when its own colour is closer to [`EDIT_COLOUR`].
pub const EDIT_COLOUR_ALT: [f32; 3] = [0.9, 0.55, 0.15];

/// The scene names, in index order.
pub fn scene_names() -> &'static [&'static str] {
    &[
        "sphere",
        "three-spheres",
        "striped-floor",
        "striped-sphere",
        "warm-light",
        "low-sun",
        "two-lights",
        "textured",
        "pastel",
        "dark-objects",
    ]
}

type Vec3 = [f32; 3];

fn add(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn scale(a: Vec3, s: f32) -> Vec3 {
    a.map(|v| v * s)
}
fn dot(a: Vec3, b: Vec3) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn normalised(a: Vec3) -> Vec3 {
    scale(a, 1.0 / dot(a, a).sqrt())
}

/// How a surface's albedo varies over it.
#[derive(Clone, Copy)]
enum Pattern {
    Flat,
    /// Alternating with the second colour in bands of this width along x (world units).
    StripesX(Vec3, f32),
    /// Alternating with the second colour in latitude bands of this many per radius.
    Bands(Vec3, f32),
    /// Multiplied by a smooth value noise of this amplitude.
    Noise(f32),
}

#[derive(Clone, Copy)]
struct Surface {
    colour: Vec3,
    pattern: Pattern,
    /// Specular strength (0: matte) and Blinn-Phong exponent.
    gloss: (f32, f32),
}

struct Sphere {
    centre: Vec3,
    radius: f32,
    surface: Surface,
}

struct DirectionalLight {
    /// Towards the light.
    direction: Vec3,
    colour: Vec3,
}

struct Setup {
    floor: Surface,
    wall: Surface,
    spheres: Vec<Sphere>,
    /// The first is the main light (the one whose cast shadows are marked).
    lights: Vec<DirectionalLight>,
    ambient: Vec3,
}

const WALL_Z: f32 = 2.2;
/// The usual sun: from the upper left behind the camera, at the same angle to the floor and
/// the wall. A crease where two surfaces meet at different angles to the light is a shape
/// problem, not an illumination one: no method without geometry tells a darker wall from a
/// less lit one. `low-sun` keeps one such case.
const FRONT_LIGHT: Vec3 = [-0.5, 0.8, -0.8];
const CAMERA: Vec3 = [0.0, 1.5, -5.0];
const LOOK_AT: Vec3 = [0.0, 0.8, 0.0];
const HALF_FOV_TAN: f32 = 0.42;

fn flat(colour: Vec3) -> Surface {
    Surface {
        colour,
        pattern: Pattern::Flat,
        gloss: (0.0, 1.0),
    }
}

fn glossy(colour: Vec3) -> Surface {
    Surface {
        colour,
        pattern: Pattern::Flat,
        gloss: (0.55, 60.0),
    }
}

fn sphere(x: f32, z: f32, radius: f32, surface: Surface) -> Sphere {
    Sphere {
        centre: [x, radius, z],
        radius,
        surface,
    }
}

fn sun(direction: Vec3, colour: Vec3) -> DirectionalLight {
    DirectionalLight {
        direction: normalised(direction),
        colour,
    }
}

fn setup(index: usize) -> Setup {
    let white_sun = |d: Vec3| vec![sun(d, [0.72; 3])];
    let grey_sky = [0.28; 3];
    let floor = flat([0.78, 0.74, 0.66]);
    let wall = flat([0.62, 0.7, 0.78]);
    match index % scene_names().len() {
        0 => Setup {
            floor,
            wall,
            spheres: vec![sphere(0.0, 0.0, 1.0, glossy([0.85, 0.2, 0.15]))],
            lights: white_sun(FRONT_LIGHT),
            ambient: grey_sky,
        },
        1 => Setup {
            floor,
            wall,
            spheres: vec![
                sphere(-1.3, 0.3, 0.7, glossy([0.85, 0.25, 0.2])),
                sphere(0.3, -0.4, 0.6, glossy([0.25, 0.7, 0.3])),
                sphere(1.5, 0.8, 0.8, glossy([0.9, 0.8, 0.2])),
            ],
            lights: white_sun(FRONT_LIGHT),
            ambient: grey_sky,
        },
        2 => Setup {
            floor: Surface {
                colour: [0.85, 0.82, 0.72],
                pattern: Pattern::StripesX([0.35, 0.55, 0.7], 0.6),
                gloss: (0.0, 1.0),
            },
            wall: flat([0.8, 0.72, 0.6]),
            spheres: vec![sphere(0.2, 0.0, 0.9, glossy([0.8, 0.3, 0.5]))],
            lights: white_sun([-0.8, 0.75, -0.7]),
            ambient: grey_sky,
        },
        3 => Setup {
            floor,
            wall,
            spheres: vec![sphere(
                0.0,
                0.0,
                1.1,
                Surface {
                    colour: [0.9, 0.75, 0.2],
                    pattern: Pattern::Bands([0.2, 0.35, 0.75], 3.0),
                    gloss: (0.5, 50.0),
                },
            )],
            lights: white_sun(FRONT_LIGHT),
            ambient: grey_sky,
        },
        4 => Setup {
            floor: flat([0.75, 0.75, 0.75]),
            wall: flat([0.7, 0.8, 0.7]),
            spheres: vec![
                sphere(-0.6, 0.0, 0.9, glossy([0.3, 0.5, 0.85])),
                sphere(1.2, 0.6, 0.6, glossy([0.85, 0.85, 0.85])),
            ],
            lights: vec![sun(FRONT_LIGHT, [0.8, 0.6, 0.35])],
            ambient: [0.16, 0.2, 0.3],
        },
        5 => Setup {
            floor,
            wall: flat([0.8, 0.62, 0.55]),
            spheres: vec![
                sphere(-0.8, 0.5, 0.8, glossy([0.3, 0.6, 0.8])),
                sphere(0.9, -0.3, 0.6, flat([0.85, 0.45, 0.2])),
            ],
            lights: white_sun([-1.0, 0.35, -0.2]),
            ambient: grey_sky,
        },
        6 => Setup {
            floor,
            wall,
            spheres: vec![sphere(0.0, 0.0, 1.0, glossy([0.8, 0.3, 0.6]))],
            lights: vec![
                sun(FRONT_LIGHT, [0.5, 0.45, 0.38]),
                sun([0.8, 0.9, -0.5], [0.22, 0.26, 0.32]),
            ],
            ambient: [0.22; 3],
        },
        7 => Setup {
            floor: Surface {
                colour: [0.75, 0.65, 0.5],
                pattern: Pattern::Noise(0.25),
                gloss: (0.0, 1.0),
            },
            wall: Surface {
                colour: [0.6, 0.72, 0.6],
                pattern: Pattern::Noise(0.2),
                gloss: (0.0, 1.0),
            },
            spheres: vec![sphere(0.0, 0.0, 1.0, glossy([0.9, 0.35, 0.2]))],
            lights: white_sun(FRONT_LIGHT),
            ambient: grey_sky,
        },
        8 => Setup {
            floor: flat([0.92, 0.88, 0.82]),
            wall: flat([0.8, 0.88, 0.95]),
            spheres: vec![
                sphere(-0.7, 0.0, 0.9, glossy([0.95, 0.7, 0.75])),
                sphere(1.1, 0.5, 0.7, glossy([0.7, 0.9, 0.75])),
            ],
            lights: white_sun(FRONT_LIGHT),
            ambient: grey_sky,
        },
        _ => Setup {
            floor,
            wall,
            spheres: vec![
                sphere(-0.7, 0.0, 0.9, glossy([0.25, 0.12, 0.1])),
                sphere(1.1, 0.4, 0.7, glossy([0.1, 0.15, 0.28])),
            ],
            lights: white_sun(FRONT_LIGHT),
            ambient: grey_sky,
        },
    }
}

/// A smooth, deterministic value noise in [-1, 1] over the plane.
fn value_noise(u: f32, v: f32) -> f32 {
    let hash = |i: i32, j: i32| {
        let mut h = (i as u32).wrapping_mul(0x8da6_b343) ^ (j as u32).wrapping_mul(0xd816_3841);
        h = (h ^ (h >> 13)).wrapping_mul(0x5bd1_e995);
        (h ^ (h >> 15)) as f32 / u32::MAX as f32 * 2.0 - 1.0
    };
    let (i, j) = (u.floor() as i32, v.floor() as i32);
    let (fu, fv) = (u - u.floor(), v - v.floor());
    let (su, sv) = (fu * fu * (3.0 - 2.0 * fu), fv * fv * (3.0 - 2.0 * fv));
    let top = hash(i, j) + su * (hash(i + 1, j) - hash(i, j));
    let bottom = hash(i, j + 1) + su * (hash(i + 1, j + 1) - hash(i, j + 1));
    top + sv * (bottom - top)
}

fn albedo_at(surface: &Surface, point: Vec3, local: Vec3) -> Vec3 {
    match surface.pattern {
        Pattern::Flat => surface.colour,
        Pattern::StripesX(other, width) => {
            if (point[0] / width).floor().rem_euclid(2.0) < 1.0 {
                surface.colour
            } else {
                other
            }
        }
        Pattern::Bands(other, per_radius) => {
            if ((local[1] + 1.0) * per_radius).floor().rem_euclid(2.0) < 1.0 {
                surface.colour
            } else {
                other
            }
        }
        Pattern::Noise(amplitude) => {
            let (u, v) = if point[2] > WALL_Z - 1e-3 {
                (point[0], point[1])
            } else {
                (point[0], point[2])
            };
            let n = 0.6 * value_noise(2.0 * u, 2.0 * v) + 0.4 * value_noise(5.0 * u, 5.0 * v);
            scale(surface.colour, 1.0 + amplitude * n)
        }
    }
}

/// Distance along `direction` from `origin` to the nearest sphere, and its index.
fn hit_sphere(spheres: &[Sphere], origin: Vec3, direction: Vec3) -> Option<(f32, usize)> {
    let mut best: Option<(f32, usize)> = None;
    for (k, s) in spheres.iter().enumerate() {
        let oc = sub(origin, s.centre);
        let b = dot(oc, direction);
        let c = dot(oc, oc) - s.radius * s.radius;
        let disc = b * b - c;
        if disc < 0.0 {
            continue;
        }
        let t = -b - disc.sqrt();
        if t > 1e-4 && best.is_none_or(|(bt, _)| t < bt) {
            best = Some((t, k));
        }
    }
    best
}

/// One camera sample: albedo, shade, light, whether the main light is cast-shadowed, and
/// whether the surface is the first sphere.
struct Sample {
    albedo: Vec3,
    shade: Vec3,
    light: Vec3,
    cast_shadow: bool,
    edited_sphere: bool,
    object: u8,
}

fn trace(setup: &Setup, direction: Vec3) -> Sample {
    let plane = |t: Option<f32>| t.filter(|&t| t > 1e-4);
    let floor_t = plane((direction[1] < 0.0).then(|| -CAMERA[1] / direction[1]));
    let wall_t = plane((direction[2] > 0.0).then(|| (WALL_Z - CAMERA[2]) / direction[2]));
    let sphere_hit = hit_sphere(&setup.spheres, CAMERA, direction);
    let mut best = (f32::INFINITY, None::<usize>, [0.0f32; 3], setup.wall);
    let mut object = 1;
    if let Some(t) = wall_t {
        best = (t, None, [0.0, 0.0, -1.0], setup.wall);
    }
    if let Some(t) = floor_t.filter(|&t| t < best.0) {
        best = (t, None, [0.0, 1.0, 0.0], setup.floor);
        object = 0;
    }
    let mut local = [0.0; 3];
    if let Some((t, k)) = sphere_hit.filter(|&(t, _)| t < best.0) {
        let s = &setup.spheres[k];
        let point = add(CAMERA, scale(direction, t));
        local = scale(sub(point, s.centre), 1.0 / s.radius);
        best = (t, Some(k), local, s.surface);
        object = 2 + k as u8;
    }
    let (t, sphere, normal, surface) = best;
    let point = add(CAMERA, scale(direction, t));
    let albedo = albedo_at(&surface, point, local).map(|v| v.clamp(0.0, 1.0));
    let mut shade = setup.ambient;
    let mut light = [0.0; 3];
    let mut cast_shadow = false;
    for (k, l) in setup.lights.iter().enumerate() {
        let facing = dot(normal, l.direction);
        if facing <= 0.0 {
            continue;
        }
        let origin = add(point, scale(normal, 1e-3));
        let occluded = hit_sphere(&setup.spheres, origin, l.direction).is_some();
        if occluded {
            cast_shadow |= k == 0 && facing > 0.1;
            continue;
        }
        shade = add(shade, scale(l.colour, facing));
        let (strength, exponent) = surface.gloss;
        if strength > 0.0 {
            let half = normalised(sub(l.direction, direction));
            let spec = dot(normal, half).max(0.0).powf(exponent);
            light = add(light, scale(l.colour, strength * spec / 0.72));
        }
    }
    Sample {
        albedo,
        shade: shade.map(|v| v.min(1.0)),
        light,
        cast_shadow,
        edited_sphere: sphere == Some(0),
        object,
    }
}

/// Scene `index` (modulo the number of scenes) at `size × size` pixels.
pub fn scene(index: usize, size: usize) -> LitScene {
    let setup = setup(index);
    let original = setup.spheres[0].surface.colour;
    let edit_colour = if dot(sub(original, EDIT_COLOUR), sub(original, EDIT_COLOUR))
        < dot(
            sub(original, EDIT_COLOUR_ALT),
            sub(original, EDIT_COLOUR_ALT),
        ) {
        EDIT_COLOUR_ALT
    } else {
        EDIT_COLOUR
    };
    let forward = normalised(sub(LOOK_AT, CAMERA));
    let right = normalised([forward[2], 0.0, -forward[0]]);
    let up = [
        forward[1] * right[2] - forward[2] * right[1],
        forward[2] * right[0] - forward[0] * right[2],
        forward[0] * right[1] - forward[1] * right[0],
    ];
    let blank = Image::filled(size, size, [0.0; 3]);
    let mut out = LitScene {
        image: blank.clone(),
        albedo: blank.clone(),
        shade: blank.clone(),
        light: blank.clone(),
        cast_shadow: vec![false; size * size],
        objects: vec![0; size * size],
        edited: blank,
    };
    const SUB: [f32; 2] = [0.25, 0.75];
    for y in 0..size {
        for x in 0..size {
            let mut shadowed = 0;
            let mut seen = [0u8; 8];
            let i = 3 * (y * size + x);
            for sy in SUB {
                for sx in SUB {
                    let u = ((x as f32 + sx) / size as f32 * 2.0 - 1.0) * HALF_FOV_TAN;
                    let v = (1.0 - (y as f32 + sy) / size as f32 * 2.0) * HALF_FOV_TAN;
                    let ray = normalised(add(forward, add(scale(right, u), scale(up, v))));
                    let s = trace(&setup, ray);
                    shadowed += usize::from(s.cast_shadow);
                    seen[usize::from(s.object)] += 1;
                    let edited_albedo = if s.edited_sphere {
                        edit_colour
                    } else {
                        s.albedo
                    };
                    for c in 0..3 {
                        let compose = |a: f32| (a * s.shade[c] + s.light[c]).clamp(0.0, 1.0) / 4.0;
                        out.image.data[i + c] += compose(s.albedo[c]);
                        out.edited.data[i + c] += compose(edited_albedo[c]);
                        out.albedo.data[i + c] += s.albedo[c] / 4.0;
                        out.shade.data[i + c] += s.shade[c] / 4.0;
                        out.light.data[i + c] += s.light[c] / 4.0;
                    }
                }
            }
            out.cast_shadow[y * size + x] = shadowed >= 3;
            // The first of the most seen objects.
            out.objects[y * size + x] = (0..seen.len())
                .rev()
                .max_by_key(|&k| seen[k])
                .map_or(0, |k| k as u8);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_scene_has_shading_shadows_and_highlights_and_composes_to_its_image() {
        for (index, name) in scene_names().iter().enumerate() {
            let s = scene(index, 48);
            let shadow = s.cast_shadow.iter().filter(|&&b| b).count();
            assert!(shadow > 20, "{name}: {shadow} cast-shadow pixels");
            let bright = s.light.data.iter().filter(|&&v| v > 0.2).count();
            assert!(bright > 0, "{name}: no highlight");
            let changed = (s.image.data.iter().zip(&s.edited.data))
                .filter(|(a, b)| (*a - *b).abs() > 0.05)
                .count();
            assert!(changed > 100, "{name}: the edit changes {changed} values");
            for (k, &v) in s.image.data.iter().enumerate() {
                let composed = (s.albedo.data[k] * s.shade.data[k] + s.light.data[k]).min(1.0);
                // Only anti-aliased edge pixels mix samples of different surfaces.
                assert!((v - composed).abs() < 0.35, "{name}: value {k}");
            }
        }
        assert_eq!(scene(3, 16).image, scene(3, 16).image);
    }
}
