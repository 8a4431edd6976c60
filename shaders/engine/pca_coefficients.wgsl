// The PCA coefficients of a frame (engine/pca_terms.wgsl), one thread per component,
// summed over the frame's texels in order.

#import gpu/for_each.wgsl
#import engine/pca_terms.wgsl

fn count() -> u32 { return p.components; }

fn each(k: u32) {
    coefficients[k] = pca_terms(k, 0u, 1u, frame_texels());
}
