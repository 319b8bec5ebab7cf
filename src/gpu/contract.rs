//! One home for the host–kernel contract of uniform parameter blocks: each block is
//! declared once, here in Rust, and its WGSL `struct` is generated from the same list
//! and prepended to the kernel's source, so that host and kernel cannot disagree on a
//! field's place (as the channel count and the block sizes are generated already).

/// Declares a `#[repr(C)]` uniform block of `u32` and `f32` fields (their names are
/// the same in Rust and WGSL) and its WGSL declaration, `WGSL`. The block's size must
/// be a multiple of 16 bytes, as uniform buffers require; a compile-time assertion
/// says so.
#[macro_export]
macro_rules! uniform_block {
    ($(#[$m:meta])* $vis:vis struct $name:ident { $($(#[$fm:meta])* $f:ident : $t:ident),* $(,)? }) => {
        $(#[$m])*
        #[repr(C)]
        #[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
        $vis struct $name {
            $($(#[$fm])* pub $f: $t,)*
        }

        impl $name {
            /// The WGSL declaration of this block.
            pub const WGSL: &'static str = concat!(
                "struct ", stringify!($name), " {\n",
                $("    ", stringify!($f), ": ", stringify!($t), ",\n",)*
                "}\n"
            );
        }

        const _: () = assert!(std::mem::size_of::<$name>() % 16 == 0, "a uniform block is a multiple of 16 bytes");
    };
}

#[cfg(test)]
mod tests {
    crate::uniform_block! {
        struct Probe {
            count: u32,
            scale: f32,
            pad0: u32,
            pad1: u32,
        }
    }

    #[test]
    fn the_wgsl_declaration_lists_the_fields_in_order() {
        assert_eq!(
            Probe::WGSL,
            "struct Probe {\n    count: u32,\n    scale: f32,\n    pad0: u32,\n    pad1: u32,\n}\n"
        );
        let p = Probe {
            count: 3,
            scale: 0.5,
            ..Probe::default()
        };
        assert_eq!(
            bytemuck::cast::<Probe, [u32; 4]>(p),
            [3, 0.5f32.to_bits(), 0, 0]
        );
    }
}
