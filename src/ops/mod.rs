//! Op inventory: every primitive op of MIPNet (architecture.md §4), its kernel pair, and its torch equivalent.
//!
//! | op | forward | backward (grads to) | torch |
//! |---|---|---|---|
//! | relu / sigmoid / tanh | `act::unary_fwd` | `act::unary_bwd` (x, from y) | `F.relu`, `torch.sigmoid`, `torch.tanh` |
//! | add / sub / mul, broadcasting | `elementwise::binary_fwd` | `elementwise::binary_bwd` (both, summed to shape) | `a + b`, `a - b`, `a * b` |
//! | alpha * x + beta | `elementwise::affine_fwd` | `elementwise::affine_fwd` with beta 0 | `x * a + b` |
//! | in-place a += b (the autograd tape's gradient sums) | `elementwise::add_assign` | — | `a.add_(b)` |
//! | sum to a broadcast shape | `elementwise::sum_to_shape` | broadcast | `g.sum_to_size(shape)` |
//! | mean over axes | `elementwise::mean_fwd` | `elementwise::mean_bwd` | `x.mean(dim, keepdim)` |
//! | cat (each input optionally through a ReLU) / slice along an axis | `shape::cat_fwd`, `shape::slice_fwd` | `shape::slice_bwd` (relu'd pieces masked by the output) | `torch.cat`, `x[..., a:b]` |
//! | batched transpose (N, R, C) -> (N, C, R) (permute NCHW <-> NHWC) | `shape::transpose_fwd` | `shape::transpose_fwd` of g | `x.transpose(1, 2).contiguous()` |
//! | iAFF attentional gate: σ(L + G) ⊙ x + (1 - σ(L + G)) ⊙ y, G broadcast over H, W | `gate::attention_gate_fwd` | `gate::attention_gate_bwd` (local, global, x, y) | sigmoid/mul/add (architecture.md §2.2) |
//! | GRU reset gate: [σ(r̃) ⊙ h, x] | `gru::gru_reset_fwd` | `gru::gru_reset_bwd` (zr, hx) | `torch.cat([torch.sigmoid(r) * h, x], 1)` |
//! | GRU update: (1 - σ(z̃)) ⊙ h + σ(z̃) ⊙ tanh(q̃) (optionally followed by x) | `gru::gru_update_fwd` | `gru::gru_update_bwd` (zr, q, hx) | sigmoid/tanh/mul/add (architecture.md §2.7) |
//! | conv2d (any kernel, stride, per-axis zero padding, bias, optional fused ReLU; Winograd F(4x4, 3x3) / F(4, 5) for stride-1 3x3 / 1x5 / 5x1 in f32, transformed kernels kept across no-grad calls; one or two outputs at stride 1 as a tap-major pointwise GEMM + shift-add) | `conv::conv2d_fwd` | `conv::conv2d_bwd` (x, w, b) | `F.conv2d` |
//! | instance norm (optional affine) | `norm::instance_norm_fwd` | `norm::instance_norm_bwd` (x, w, b) | `F.instance_norm` |
//! | batch norm (train / eval) | `norm::batch_norm_fwd` | `norm::batch_norm_bwd` (x, w, b) | `F.batch_norm` |
//! | avg_pool2d (padding, ceil_mode, count_include_pad, divisor_override) | `pool::avg_pool2d_fwd` | `pool::avg_pool2d_bwd` (x) | `F.avg_pool2d` |
//! | softmax along an axis | `softmax::softmax_fwd` | `softmax::softmax_bwd` (x, from y) | `torch.softmax` |
//! | pad (zeros / replicate) | `pad::pad2d_fwd` | `pad::pad2d_bwd` (x) | `F.pad` |
//! | grid_sample (bilinear; zeros / border; align_corners) | `sample::grid_sample_fwd` | `sample::grid_sample_bwd` (x, grid) | `F.grid_sample` |
//! | interpolate bilinear (align_corners True / False) | `sample::interpolate_bilinear_fwd` | `sample::interpolate_bilinear_bwd` (x) | `F.interpolate` |
//! | unfold / fold (any kernel, dilation, zero padding, stride) | `sample::unfold_fwd`, `sample::fold_fwd` | each other | `F.unfold`, `F.fold` |
//! | IP correlation (seed stack, grouped channel mean) | `corr::ip_corr_fwd` | `corr::ip_corr_bwd` (fl, stack) | view/mul/mean (architecture.md §2.5) |
//! | RLS correlation (rx x ry window) | `corr::rls_corr_fwd` | `corr::rls_corr_bwd` (fl, warped) | pad/slice/mul/mean (architecture.md §2.6) |
//! | IP correlation fused with the horizontal warp (f_y = 0; channels-last features) | `warp_corr::ip_warp_corr_fwd` | `warp_corr::ip_warp_corr_bwd` (fl, fr) | grid_sample + view/mul/mean (architecture.md §2.3, §2.5) |
//! | RLS correlation fused with the horizontal warp (f_y = 0; channels-last features) | `warp_corr::rls_warp_corr_fwd` | `warp_corr::rls_warp_corr_bwd` (fl, fr) | grid_sample + pad/slice/mul/mean (architecture.md §2.3, §2.6) |
//! | convex x4 upsampling | `upsample::convex_upsample_fwd` | `upsample::convex_upsample_bwd` (flow, mask) | softmax/unfold/sum (architecture.md §2.8) |
//! | masked L1 sequence loss term | `loss::masked_l1_fwd` | `loss::masked_l1_bwd` (pred) | `(d - gt).abs()[valid].mean()` |

pub mod act;
pub mod conv;
pub mod corr;
pub mod elementwise;
pub mod gate;
pub mod gru;
pub mod lanes;
pub mod loss;
pub mod norm;
pub mod pad;
pub mod pool;
pub mod sample;
pub mod shape;
pub mod softmax;
pub mod upsample;
pub mod warp_corr;
