//! The WGSL sources embedded in the binary, and host/shader structs from one definition.
//! `gpu_struct!` declares a struct once; Rust gets a `Pod` type and WGSL gets its text.

use std::borrow::Cow;

use super::precision::Precision;

/// Threads per workgroup of the 1-D kernels (`WORKGROUP` in the prelude below).
pub const WORKGROUP_SIZE: u32 = 64;

/// A Rust type with a WGSL spelling of the same size and alignment.
pub trait WgslType {
    const WGSL: &'static str;
}

macro_rules! wgsl_type {
    ($($rust:ty => $wgsl:literal),* $(,)?) => {
        $(impl WgslType for $rust { const WGSL: &'static str = $wgsl; })*
    };
}

wgsl_type! {
    u32 => "u32",
    i32 => "i32",
    f32 => "f32",
    [f32; 4] => "vec4<f32>",
    [u32; 4] => "vec4<u32>",
    glam::Vec4 => "vec4<f32>",
    glam::Mat4 => "mat4x4<f32>",
}

/// Declares a `#[repr(C)]` struct shared with WGSL. Use only 4- and 16-byte-aligned
/// field types in an order without implicit padding; a test checks every shared struct's
/// size and field offsets against naga's layout of the generated WGSL.
#[macro_export]
macro_rules! gpu_struct {
    ($(#[$meta:meta])* pub struct $name:ident { $($(#[$fmeta:meta])* pub $field:ident : $ty:ty),* $(,)? }) => {
        $(#[$meta])*
        #[repr(C)]
        #[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
        pub struct $name { $($(#[$fmeta])* pub $field: $ty),* }

        impl $crate::gpu::shaders::GpuStruct for $name {
            const NAME: &'static str = stringify!($name);
            fn wgsl() -> String {
                let mut out = format!("struct {} {{\n", stringify!($name));
                $(out.push_str(&format!(
                    "    {}: {},\n",
                    stringify!($field),
                    <$ty as $crate::gpu::shaders::WgslType>::WGSL
                ));)*
                out.push_str("}\n");
                out
            }
            fn field_offsets() -> Vec<(&'static str, usize)> {
                vec![$((stringify!($field), std::mem::offset_of!($name, $field))),*]
            }
        }
    };
}

/// A struct declared by [`gpu_struct!`].
pub trait GpuStruct: bytemuck::Pod {
    const NAME: &'static str;
    /// The WGSL declaration of this struct.
    fn wgsl() -> String;
    /// Each field's name and byte offset on the host.
    fn field_offsets() -> Vec<(&'static str, usize)>;
}

/// Host-side description of a shared struct, for the shader registry and its tests.
#[derive(Clone, Copy)]
pub struct SharedStruct {
    pub name: &'static str,
    pub wgsl: fn() -> String,
    pub size: usize,
    pub field_offsets: fn() -> Vec<(&'static str, usize)>,
}

impl SharedStruct {
    pub const fn of<T: GpuStruct>() -> Self {
        Self {
            name: T::NAME,
            wgsl: T::wgsl,
            size: std::mem::size_of::<T>(),
            field_offsets: T::field_offsets,
        }
    }
}

/// One WGSL file of `shaders/`, with the shared structs it uses (prepended on load).
#[derive(Clone, Copy)]
pub struct Shader {
    pub file: &'static str,
    pub body: &'static str,
    pub structs: &'static [SharedStruct],
    /// Needs `enable f16;` support (SHADER_F16) in every variant.
    pub needs_f16: bool,
    /// Needs subgroup operations (SUBGROUP).
    pub needs_subgroups: bool,
    /// Stores its tensors as `Elem`, built as f32 or f16 (see [`Precision`]).
    pub elem: bool,
    /// Rust constants declared as WGSL `const NAME: f32` before the file (one definition).
    pub constants: &'static [(&'static str, f32)],
    /// Rust constants declared as WGSL `const NAME: u32` before the file.
    pub uints: &'static [(&'static str, u32)],
}

mod files {
    include!(concat!(env!("OUT_DIR"), "/shader_files.rs"));
}

/// Every file under `shaders/` (embedded by `build.rs`): its path there and its text.
pub fn files() -> &'static [(&'static str, &'static str)] {
    files::FILES
}

/// The text of the file at `path` under `shaders/`, if there is one.
pub fn file(path: &str) -> Option<&'static str> {
    files::FILES
        .iter()
        .find(|(name, _)| *name == path)
        .map(|(_, text)| *text)
}

/// A shader's text with its imports expanded, and the files it included.
#[derive(Debug, PartialEq)]
pub struct Expanded {
    pub text: String,
    /// Every file imported, directly or through others, in the order first named.
    pub imports: Vec<String>,
}

/// The WGSL preprocessor, two directives, each a line of its own:
/// - `#import PATH` (a file under `shaders/`) is replaced by that file, itself expanded
///   the same way. A file is included once per shader, where it is first named (WGSL
///   declarations may come in any order), so two files may import a third and imports
///   may not loop. An unknown path is an error naming it and the file that asks for it.
/// - `#bind NAMES: ACCESS TYPE` declares a kernel's bindings in group 0, numbered in the
///   order they appear in the expanded shader (the order the dispatch binds its buffers
///   in): NAMES is one name or several, comma-separated; ACCESS is `uniform`, `read` or
///   `read_write` (a storage buffer), or left out for a texture. `#bind x, y: read
///   array<f32>` is `@group(0) @binding(0) var<storage, read> x: array<f32>;` and the
///   same for `y` at binding 1.
pub fn expand(file_name: &str, text: &str) -> Result<Expanded, String> {
    expand_with(file_name, text, &|path| file(path))
}

/// [`expand`] over any file table (`lookup`), for tests.
pub fn expand_with(
    file_name: &str,
    text: &str,
    lookup: &dyn Fn(&str) -> Option<&'static str>,
) -> Result<Expanded, String> {
    struct State {
        seen: Vec<String>,
        out: String,
        binding: u32,
    }
    fn walk(
        name: &str,
        text: &str,
        lookup: &dyn Fn(&str) -> Option<&'static str>,
        state: &mut State,
    ) -> Result<(), String> {
        for line in text.lines() {
            if let Some(binds) = line.strip_prefix("#bind ") {
                for declaration in bindings(binds, state.binding)
                    .map_err(|problem| format!("{name}: #bind {binds}: {problem}"))?
                {
                    state.out.push_str(&declaration);
                    state.out.push('\n');
                    state.binding += 1;
                }
                continue;
            }
            match line.strip_prefix("#import ") {
                Some(path) => {
                    let path = path.trim();
                    if state.seen.iter().any(|s| s == path) {
                        continue;
                    }
                    state.seen.push(path.to_string());
                    let imported = lookup(path).ok_or_else(|| {
                        format!("{name}: #import {path}: no such file in shaders/")
                    })?;
                    walk(path, imported, lookup, state)?;
                }
                None => {
                    state.out.push_str(line);
                    state.out.push('\n');
                }
            }
        }
        Ok(())
    }
    let mut state = State {
        seen: vec![file_name.to_string()],
        out: String::new(),
        binding: 0,
    };
    walk(file_name, text, lookup, &mut state)?;
    state.seen.remove(0);
    Ok(Expanded {
        text: state.out,
        imports: state.seen,
    })
}

/// The declarations of one `#bind` line's text (`NAMES: ACCESS TYPE`), the first at
/// binding `first`.
fn bindings(text: &str, first: u32) -> Result<Vec<String>, String> {
    let (names, kind) = text.split_once(':').ok_or("expected NAMES: ACCESS TYPE")?;
    let kind = kind.trim();
    let (access, rest) = kind.split_once(' ').unwrap_or((kind, ""));
    let (space, ty) = match access {
        "uniform" => ("<uniform>", rest.trim()),
        "read" => ("<storage, read>", rest.trim()),
        "read_write" => ("<storage, read_write>", rest.trim()),
        _ if kind.starts_with("texture") => ("", kind),
        _ => {
            return Err(
                "the access must be uniform, read or read_write (or none, for a texture)".into(),
            );
        }
    };
    let names: Vec<&str> = names.split(',').map(str::trim).collect();
    let word = |w: &str| !w.is_empty() && w.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
    if ty.is_empty() || !names.iter().all(|n| word(n)) {
        return Err("expected NAMES: ACCESS TYPE".into());
    }
    Ok(names
        .iter()
        .zip(first..)
        .map(|(name, binding)| format!("@group(0) @binding({binding}) var{space} {name}: {ty};"))
        .collect())
}

/// What every shader starts with (after its `enable` and `Elem` lines): the workgroup
/// size of the 1-D kernels from [`WORKGROUP_SIZE`], the
/// entry point's builtins with the workgroup's and the invocation's index in a 2-D grid
/// (see [`Grid`](super::kernel::Grid)), and the fetch of one texel of a flat array held
/// as [`Texels`](super::texels::Texels), so no kernel repeats them.
pub fn prelude() -> String {
    format!(
        "const WORKGROUP: u32 = {}u;
struct Invocation {{
    @builtin(workgroup_id) group: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) lane: u32,
}}
// The workgroup's index in the 2-D grid, and its first invocation's when every
// workgroup has WORKGROUP invocations.
fn group_index(invocation: Invocation) -> u32 {{
    return invocation.group.x + invocation.group.y * invocation.groups.x;
}}
fn linear_index(invocation: Invocation) -> u32 {{
    return group_index(invocation) * WORKGROUP + invocation.lane;
}}
const TEXEL_ROW: u32 = {}u;
// Texel `i` (values 4i … 4i + 3) of a flat array held as texels (src/gpu/texels.rs).
fn texel(t: texture_2d<f32>, i: u32) -> vec4<f32> {{
    return textureLoad(t, vec2<u32>(i & (TEXEL_ROW - 1u), i / TEXEL_ROW), 0);
}}
fn texel_u32(t: texture_2d<u32>, i: u32) -> vec4<u32> {{
    return textureLoad(t, vec2<u32>(i & (TEXEL_ROW - 1u), i / TEXEL_ROW), 0);
}}
",
        WORKGROUP_SIZE,
        super::texels::TEXEL_ROW
    )
}

impl Shader {
    /// This shader with `constants` declared in its prelude.
    pub const fn with_constants(self, constants: &'static [(&'static str, f32)]) -> Self {
        Self { constants, ..self }
    }

    /// This shader with integer `uints` declared in its prelude.
    pub const fn with_uints(self, uints: &'static [(&'static str, u32)]) -> Self {
        Self { uints, ..self }
    }

    /// Whether the variant for `precision` needs SHADER_F16.
    pub fn needs_f16_for(&self, precision: Precision) -> bool {
        self.needs_f16 || (self.elem && precision == Precision::F16)
    }

    /// The full WGSL source of one variant: `enable f16;` where needed, the `Elem` alias,
    /// the shared struct declarations, then the file. (naga takes subgroup builtins
    /// without a directive.)
    pub fn source(&self, precision: Precision) -> String {
        let mut out = String::new();
        if self.needs_f16_for(precision) {
            out.push_str("enable f16;\n");
        }
        if self.elem {
            let elem = match precision {
                Precision::F32 => "f32",
                Precision::F16 => "f16",
            };
            out.push_str(&format!("alias Elem = {elem};\n"));
        }
        out.push_str(&prelude());
        for (name, value) in self.constants {
            out.push_str(&format!("const {name}: f32 = {value:?};\n"));
        }
        for (name, value) in self.uints {
            out.push_str(&format!("const {name}: u32 = {value}u;\n"));
        }
        for s in self.structs {
            out.push_str(&(s.wgsl)());
        }
        // An import that does not resolve is left as it stands, so that naga's error
        // shows it (the shader tests expand every file and name the missing path).
        match expand(self.file, self.body) {
            Ok(expanded) => out.push_str(&expanded.text),
            Err(_) => out.push_str(self.body),
        }
        out
    }

    /// The files this shader's text imports, directly or through others, or the error
    /// naming an import that does not resolve.
    pub fn imports(&self) -> Result<Vec<String>, String> {
        expand(self.file, self.body).map(|expanded| expanded.imports)
    }

    /// The group-0 bindings of the variant for `precision` as naga reflects them:
    /// (binding, is a uniform), sorted by binding.
    pub fn bindings(&self, precision: Precision) -> Result<Vec<(u32, bool)>, String> {
        let source = self.source(precision);
        let module = wgpu::naga::front::wgsl::parse_str(&source)
            .map_err(|e| format!("{}: {}", self.file, e.emit_to_string(&source)))?;
        let mut out: Vec<(u32, bool)> = module
            .global_variables
            .iter()
            .filter_map(|(_, v)| {
                let b = v.binding.as_ref()?;
                (b.group == 0).then_some((b.binding, v.space == wgpu::naga::AddressSpace::Uniform))
            })
            .collect();
        out.sort();
        Ok(out)
    }

    pub fn module(&self, device: &wgpu::Device, precision: Precision) -> wgpu::ShaderModule {
        device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(self.file),
            source: wgpu::ShaderSource::Wgsl(Cow::Owned(self.source(precision))),
        })
    }
}

/// Declares a [`Shader`] from a file under `shaders/` and the shared structs it uses
/// (`elem`: built as f32 and f16 variants). Stages declare their own shaders with it.
#[macro_export]
macro_rules! wgsl_shader {
    ($file:literal, [$($s:ty),*], elem) => {
        $crate::wgsl_shader!($file, [$($s),*], f16: false, subgroups: false, elem: true)
    };
    ($file:literal, [$($s:ty),*], f16: $f16:expr, subgroups: $sg:expr) => {
        $crate::wgsl_shader!($file, [$($s),*], f16: $f16, subgroups: $sg, elem: false)
    };
    ($file:literal, [$($s:ty),*], f16: $f16:expr, subgroups: $sg:expr, elem: $elem:expr) => {
        $crate::gpu::shaders::Shader {
            file: $file,
            body: include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/shaders/", $file)),
            structs: &[$($crate::gpu::shaders::SharedStruct::of::<$s>()),*],
            needs_f16: $f16,
            needs_subgroups: $sg,
            elem: $elem,
            constants: &[],
            uints: &[],
        }
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table(path: &str) -> Option<&'static str> {
        match path {
            "a.wgsl" => Some("#import c.wgsl\nfn a() {}\n"),
            "b.wgsl" => Some("#import c.wgsl\nfn b() {}\n"),
            "c.wgsl" => Some("fn c() {}\n"),
            "loop.wgsl" => Some("#import loop.wgsl\nfn l() {}\n"),
            _ => None,
        }
    }

    #[test]
    fn an_import_is_replaced_by_its_file_once_where_first_named() {
        let out = expand_with(
            "s.wgsl",
            "#import a.wgsl\n#import b.wgsl\nfn main() {}",
            &table,
        );
        let expected = Expanded {
            text: "fn c() {}\nfn a() {}\nfn b() {}\nfn main() {}\n".into(),
            imports: vec!["a.wgsl".into(), "c.wgsl".into(), "b.wgsl".into()],
        };
        assert_eq!(out.unwrap(), expected);
    }

    #[test]
    fn a_file_that_imports_itself_is_included_once() {
        let out = expand_with("s.wgsl", "#import loop.wgsl\n", &table);
        let out = out.unwrap();
        assert_eq!(
            (out.text.as_str(), out.imports),
            ("fn l() {}\n", vec!["loop.wgsl".into()])
        );
    }

    #[test]
    fn an_unknown_import_names_the_path_and_the_file_that_asks() {
        let err = expand_with("s.wgsl", "#import a.wgsl\n#import nope.wgsl\n", &table);
        assert_eq!(
            err.unwrap_err(),
            "s.wgsl: #import nope.wgsl: no such file in shaders/"
        );
    }

    #[test]
    fn only_a_line_that_starts_with_the_directive_imports() {
        let text = "// #import a.wgsl\n  #import_not\nfn f() {}\n";
        let out = expand_with("s.wgsl", text, &table).unwrap();
        assert_eq!((out.text.as_str(), out.imports.len()), (text, 0));
    }

    #[test]
    fn bindings_are_numbered_in_order_across_imports() {
        let lookup = |path: &str| match path {
            "shared.wgsl" => Some("#bind t: texture_2d<f32>\n"),
            _ => None,
        };
        let text = "#bind p: uniform Params\n#import shared.wgsl\n// y\n#bind x, y: read_write array<Elem>\n";
        let out = expand_with("s.wgsl", text, &lookup).unwrap();
        assert_eq!(
            out.text,
            "@group(0) @binding(0) var<uniform> p: Params;\n\
             @group(0) @binding(1) var t: texture_2d<f32>;\n\
             // y\n\
             @group(0) @binding(2) var<storage, read_write> x: array<Elem>;\n\
             @group(0) @binding(3) var<storage, read_write> y: array<Elem>;\n"
        );
    }

    #[test]
    fn a_bind_line_that_cannot_be_read_names_the_file_and_the_line() {
        for (line, problem) in [
            ("#bind x array<f32>", "expected NAMES: ACCESS TYPE"),
            ("#bind x: write array<f32>", "the access must be uniform"),
            ("#bind x y: read array<f32>", "expected NAMES: ACCESS TYPE"),
            ("#bind x: read ", "expected NAMES: ACCESS TYPE"),
            ("#bind : read array<f32>", "expected NAMES: ACCESS TYPE"),
        ] {
            let err = expand_with("s.wgsl", line, &table).unwrap_err();
            let rest = line.strip_prefix("#bind ").unwrap();
            assert!(
                err.starts_with(&format!("s.wgsl: #bind {rest}: {problem}")),
                "{line}: {err}"
            );
        }
    }

    #[test]
    fn the_embedded_table_holds_every_shader_file() {
        assert!(file("gpu/for_each.wgsl").is_some_and(|t| t.contains("fn main")));
        assert!(file("gpu/none.wgsl").is_none());
    }
}
