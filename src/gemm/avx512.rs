//! f32 GEMM for AVX-512 CPUs: packed panels and an 8 x 48 register-blocked micro-kernel.
//!
//! matrixmultiply's AVX-512 sgemm kernel (16 x 16) issues one load per FMA, which caps it near 80%
//! of the FMA peak; this kernel keeps 24 accumulators (8 rows of C, each 48 columns as three zmm
//! vectors) and issues 11 loads per 24 FMAs. Blocking: B in KC x NC blocks packed into NR-column
//! panels, A in MC x KC blocks packed into MR-row panels (BLIS loop order). Every C element is
//! summed over k in increasing order, one KC block after the other, whatever the shapes and the
//! block it falls in, so results do not depend on how callers tile C.

use std::arch::x86_64::*;
use std::cell::RefCell;

/// Rows of C per micro-kernel call (values of A broadcast per k).
const MR: usize = 8;
/// Columns of C per micro-kernel call (three zmm vectors of B per k).
const NR: usize = 48;
/// Depth of a packed block.
const KC: usize = 384;
/// Rows of A packed at a time.
const MC: usize = 192;
/// Columns of B packed at a time (a KC x NC block, 720 KiB, stays in L2).
const NC: usize = NR * 10;

/// One 64-byte aligned vector: the unit of the packing buffers (aligned loads of B).
#[repr(C, align(64))]
#[derive(Clone, Copy)]
struct Line([f32; 16]);

thread_local! {
    /// This thread's packing buffers (A panels, B panels), reused across calls.
    static BUFS: RefCell<(Vec<Line>, Vec<Line>)> = const { RefCell::new((Vec::new(), Vec::new())) };
}

/// Whether this CPU runs the kernel.
pub fn available() -> bool {
    is_x86_feature_detected!("avx512f")
}

/// Address of element (i, j) of a strided matrix.
#[inline(always)]
unsafe fn at(p: *const f32, i: usize, j: usize, rs: isize, cs: isize) -> *const f32 {
    unsafe { p.offset(i as isize * rs + j as isize * cs) }
}

/// dst[t·ds + i] = src[i·ss + t] for i, t in 0..8: an 8 x 8 transpose in AVX registers.
#[target_feature(enable = "avx")]
unsafe fn transpose8(src: *const f32, ss: isize, dst: *mut f32, ds: usize) {
    unsafe {
        let r: [__m256; 8] = std::array::from_fn(|i| _mm256_loadu_ps(src.offset(i as isize * ss)));
        let t0 = _mm256_unpacklo_ps(r[0], r[1]);
        let t1 = _mm256_unpackhi_ps(r[0], r[1]);
        let t2 = _mm256_unpacklo_ps(r[2], r[3]);
        let t3 = _mm256_unpackhi_ps(r[2], r[3]);
        let t4 = _mm256_unpacklo_ps(r[4], r[5]);
        let t5 = _mm256_unpackhi_ps(r[4], r[5]);
        let t6 = _mm256_unpacklo_ps(r[6], r[7]);
        let t7 = _mm256_unpackhi_ps(r[6], r[7]);
        let u0 = _mm256_shuffle_ps::<0x44>(t0, t2);
        let u1 = _mm256_shuffle_ps::<0xEE>(t0, t2);
        let u2 = _mm256_shuffle_ps::<0x44>(t1, t3);
        let u3 = _mm256_shuffle_ps::<0xEE>(t1, t3);
        let u4 = _mm256_shuffle_ps::<0x44>(t4, t6);
        let u5 = _mm256_shuffle_ps::<0xEE>(t4, t6);
        let u6 = _mm256_shuffle_ps::<0x44>(t5, t7);
        let u7 = _mm256_shuffle_ps::<0xEE>(t5, t7);
        let out = [
            _mm256_permute2f128_ps::<0x20>(u0, u4),
            _mm256_permute2f128_ps::<0x20>(u1, u5),
            _mm256_permute2f128_ps::<0x20>(u2, u6),
            _mm256_permute2f128_ps::<0x20>(u3, u7),
            _mm256_permute2f128_ps::<0x31>(u0, u4),
            _mm256_permute2f128_ps::<0x31>(u1, u5),
            _mm256_permute2f128_ps::<0x31>(u2, u6),
            _mm256_permute2f128_ps::<0x31>(u3, u7),
        ];
        for (t, o) in out.iter().enumerate() {
            _mm256_storeu_ps(dst.add(t * ds), *o);
        }
    }
}

/// Packs a `width`-wide panel from a matrix whose panel index runs along `ps` and depth along `ks`:
/// dst[kk·width + j] = src[j·ps + kk·ks] for kk < kc, j < used (zero for used ≤ j < width). When
/// depth is contiguous (ks = 1) the copy goes by 8 x 8 register transposes.
unsafe fn pack_panel(kc: usize, used: usize, width: usize, src: *const f32, ps: isize, ks: isize, dst: *mut f32) {
    unsafe {
        if ps == 1 && used == width {
            for kk in 0..kc {
                // dst row kk = src(kk, 0..width), contiguous
                std::ptr::copy_nonoverlapping(src.offset(kk as isize * ks), dst.add(kk * width), width);
            }
            return;
        }
        let (mut j0, mut k8) = (0, 0);
        if ks == 1 {
            // whole 8 x 8 blocks: dst[(k0 + t)·width + j0 + i] = src[(j0 + i)·ps + k0 + t]
            k8 = kc / 8 * 8;
            while j0 + 8 <= used {
                for k0 in (0..k8).step_by(8) {
                    transpose8(src.offset(j0 as isize * ps + k0 as isize), ps, dst.add(k0 * width + j0), width);
                }
                j0 += 8;
            }
        }
        for j in 0..width {
            // the rest element by element: columns past the 8-blocks, and the depth tail of the others
            let from = if j < j0 { k8 } else { 0 };
            for kk in from..kc {
                *dst.add(kk * width + j) =
                    if j < used { *src.offset(j as isize * ps + kk as isize * ks) } else { 0.0 };
            }
        }
    }
}

/// Packs A[0..mc, 0..kc] into MR-row panels, pa[panel][kk][i], zero rows past mc.
unsafe fn pack_a(mc: usize, kc: usize, a: *const f32, rsa: isize, csa: isize, pa: *mut f32) {
    for (p, i0) in (0..mc).step_by(MR).enumerate() {
        // panel p holds rows i0..i0 + MR: panel index i along rsa, depth kk along csa
        unsafe { pack_panel(kc, MR.min(mc - i0), MR, at(a, i0, 0, rsa, csa), rsa, csa, pa.add(p * kc * MR)) };
    }
}

/// Packs B[0..kc, 0..nc] into NR-column panels, pb[panel][kk][j], zero columns past nc.
unsafe fn pack_b(kc: usize, nc: usize, b: *const f32, rsb: isize, csb: isize, pb: *mut f32) {
    for (p, j0) in (0..nc).step_by(NR).enumerate() {
        // panel p holds columns j0..j0 + NR: panel index j along csb, depth kk along rsb
        unsafe { pack_panel(kc, NR.min(nc - j0), NR, at(b, 0, j0, rsb, csb), csb, rsb, pb.add(p * kc * NR)) };
    }
}

/// C[0..rows, 0..cols] <- alpha · Apanel · Bpanel + beta · C (C not read when beta is 0).
#[target_feature(enable = "avx512f")]
#[allow(clippy::too_many_arguments)]
unsafe fn kernel(kc: usize, pa: *const f32, pb: *const f32, alpha: f32, beta: f32, c: *mut f32, rsc: isize,
                 csc: isize, rows: usize, cols: usize) {
    let mut acc = [[_mm512_setzero_ps(); 3]; MR];
    let (mut a, mut b) = (pa, pb);
    for _ in 0..kc {
        // acc[i][v] += A(i, kk) · B(kk, 16v..16v + 16)
        let bv = unsafe { [_mm512_load_ps(b), _mm512_load_ps(b.add(16)), _mm512_load_ps(b.add(32))] };
        for (i, row) in acc.iter_mut().enumerate() {
            let ai = _mm512_set1_ps(unsafe { *a.add(i) });
            for (r, &bvv) in row.iter_mut().zip(&bv) {
                *r = _mm512_fmadd_ps(ai, bvv, *r);
            }
        }
        a = a.wrapping_add(MR);
        b = b.wrapping_add(NR);
    }
    let (av, bv) = (_mm512_set1_ps(alpha), _mm512_set1_ps(beta));
    if csc == 1 {
        // lanes of vector v holding columns < cols
        let masks: [__mmask16; 3] =
            std::array::from_fn(|v| ((1u32 << cols.saturating_sub(16 * v).min(16)) - 1) as __mmask16);
        for (i, row) in acc.iter().enumerate().take(rows) {
            for (v, &r) in row.iter().enumerate() {
                unsafe {
                    let p = c.offset(i as isize * rsc).add(16 * v);
                    let mut out = _mm512_mul_ps(av, r);
                    if beta != 0.0 {
                        out = _mm512_fmadd_ps(bv, _mm512_maskz_loadu_ps(masks[v], p), out);
                    }
                    _mm512_mask_storeu_ps(p, masks[v], out);
                }
            }
        }
    } else {
        let mut tmp = [Line([0.0; 16]); 3];
        for row in acc.iter().take(rows).enumerate() {
            let (i, row) = row;
            for (t, &r) in tmp.iter_mut().zip(row) {
                unsafe { _mm512_store_ps(t.0.as_mut_ptr(), _mm512_mul_ps(av, r)) };
            }
            for j in 0..cols {
                unsafe {
                    let p = c.offset(i as isize * rsc + j as isize * csc);
                    let r = tmp[j / 16].0[j % 16];
                    *p = if beta != 0.0 { r + beta * *p } else { r };
                }
            }
        }
    }
}

/// C <- alpha · A·B + beta · C on raw strided storage (A: m x k, B: k x n, C: m x n, all non-empty).
///
/// # Safety
/// The CPU has AVX-512F ([`available`]); pointers and strides describe valid memory of those sizes,
/// and C does not alias A or B.
#[allow(clippy::too_many_arguments)]
pub unsafe fn sgemm(m: usize, k: usize, n: usize, alpha: f32, a: *const f32, rsa: isize, csa: isize,
                    b: *const f32, rsb: isize, csb: isize, beta: f32, c: *mut f32, rsc: isize, csc: isize) {
    let need_a = MC.min(m).div_ceil(MR) * MR * KC.min(k) / 16 + 1;
    let need_b = NC.min(n).div_ceil(NR) * NR * KC.min(k) / 16 + 1;
    let run = |pa: *mut f32, pb: *mut f32| {
        for jc in (0..n).step_by(NC) {
            let nc = NC.min(n - jc);
            for pc in (0..k).step_by(KC) {
                let kc = KC.min(k - pc);
                // later K blocks add to what the first one wrote
                let beta = if pc == 0 { beta } else { 1.0 };
                unsafe {
                    pack_b(kc, nc, at(b, pc, jc, rsb, csb), rsb, csb, pb);
                    for ic in (0..m).step_by(MC) {
                        let mc = MC.min(m - ic);
                        pack_a(mc, kc, at(a, ic, pc, rsa, csa), rsa, csa, pa);
                        for (jp, jr) in (0..nc).step_by(NR).enumerate() {
                            for (ip, ir) in (0..mc).step_by(MR).enumerate() {
                                // C block (ic + ir, jc + jr) of at most MR x NR
                                kernel(kc, pa.add(ip * kc * MR), pb.add(jp * kc * NR), alpha, beta,
                                       c.offset((ic + ir) as isize * rsc + (jc + jr) as isize * csc), rsc, csc,
                                       MR.min(mc - ir), NR.min(nc - jr));
                            }
                        }
                    }
                }
            }
        }
    };
    BUFS.with(|bufs| match bufs.try_borrow_mut() {
        Ok(mut bufs) => {
            let (pa, pb) = &mut *bufs;
            if pa.len() < need_a {
                pa.resize(need_a, Line([0.0; 16]));
            }
            if pb.len() < need_b {
                pb.resize(need_b, Line([0.0; 16]));
            }
            run(pa.as_mut_ptr().cast(), pb.as_mut_ptr().cast());
        }
        Err(_) => {
            let (mut pa, mut pb) = (vec![Line([0.0; 16]); need_a], vec![Line([0.0; 16]); need_b]);
            run(pa.as_mut_ptr().cast(), pb.as_mut_ptr().cast());
        }
    });
}
