"""``ExtractionSettings``: every tuning of the rod extraction, each with the measurement behind it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ExtractionSettings:
    """Tuning of ``find_rod_centre``; the defaults suit a UTM-30LX-EW and a 5-25 mm rod."""

    background_sigmas: float = 4.0
    min_depth_below_background_m: float = 0.01
    default_range_sigma_m: float = 0.01
    range_sigma_floor_m: float = 1e-4
    beam_angle_sigma_rad: float = 2e-4
    #: Width of one beam's spot (UTM-30LX-EW: one 0.25 deg step). At the rod's silhouette a
    #: partly covered spot returns from anywhere across its covered part, so the two edge
    #: beams' lateral position has an extra ``footprint / sqrt(12)`` of uncertainty.
    beam_footprint_rad: float = float(np.radians(0.25))
    min_jump_m: float = 0.01
    #: A candidate must span at least this fraction of the angle the rod covers at its range ...
    min_visible_fraction: float = 0.6
    #: ... or this fraction when a background scan shows a surface more than ``echo_merge_m``
    #: behind it: a rod darker than that surface shows only its middle, where its own echo is
    #: the stronger (the scanner reports the strongest; a dark 10 mm rod at 0.15 m before a
    #: wall 2.5 m behind: 12 of its 27 beams), and those beams read the rod alone. (With a
    #: surface close behind, a narrow core is a rod whose flanks merged with it, and its
    #: front beams are blends too: 20 mm rods at 0.1-1 m before a wall 0.3 m behind came out
    #: 3-40 mm off with too small a std; they keep the fraction above.) Such a core's
    #: sideways position, from a nearly flat arc, is checked against the range profile's
    #: symmetry (``_with_symmetry_doubt``), as a fit of few beams is.
    min_visible_fraction_far_background: float = 0.25
    min_beams: int = 3
    min_beams_for_radius: int = 8
    min_arc_span_for_radius_deg: float = 100.0
    edge_residual_sigmas: float = 4.0
    max_edge_drops_per_side: int = 1
    #: A beam of an averaged scan is *unstable* (it flipped between surfaces during the dwell:
    #: a mixed pixel at a depth edge) when fewer than this fraction of the scans agreed on it ...
    min_stable_fraction: float = 0.8
    #: ... or when its reading spread exceeds this many times the scan's median reading spread.
    max_spread_ratio: float = 4.0
    #: Steady mixed pixels: a real scanner's spot is wider than its beam step, so at a depth
    #: edge up to this many beams per side ramp from the rod's range out to the background
    #: (issue 18: 4-16 beams in 25-100 mm steps, as steady as the rod). A segment may be this
    #: much wider than the rod; the rod's own beams are picked out of it (``_rod_core``).
    max_ramp_beams: int = 16
    #: How far a beam may lie off the rod's surface and still be taken as the rod's, beyond
    #: ``edge_residual_sigmas`` of its noise: the rod's shape and the scanner's range bias
    #: (a fraction of the radius, at least ``min_shape_tolerance_m``).
    shape_tolerance_fraction: float = 0.1
    min_shape_tolerance_m: float = 0.002
    #: The scanner's range error the size checks allow for (UTM-30LX-EW data sheet: +-30 mm
    #: accuracy): a near rod seen 12 mm too far looks narrower than its range says.
    range_bias_allowance_m: float = 0.03
    #: A range error the solver's curve moves each centre by along its bearing; a near or thick
    #: rod's centre moves by a little less (its beams fan out over the arc). What is left, for
    #: a range error this large (issue 18's real data: +12 mm at 0.15 m, -13 mm at 0.75 m),
    #: joins the covariance.
    typical_range_error_m: float = 0.012
    #: The beam's spot, ``width + divergence * range`` wide (1/e^2 of a gaussian): the UTM-30LX-EW
    #: data sheet's "minimum detectable width 130 mm at 10 m" (docs/scanner-model.md). A beam whose
    #: spot passes partly beside the rod also returns light from what lies behind it ...
    spot_width_at_scanner_m: float = 0.020
    spot_divergence_rad: float = 0.011
    #: Whether the centre along the bearing may come from a fit against the spot
    #: (``_along_the_spot``); False keeps the ray fit's. A twist drill's fits (``fluted``) and
    #: the flute phase's plain ones keep it: their offsets were measured against ray fits
    #: (docs/lab/solver-log.md, "Mended").
    fit_along_the_spot: bool = True
    #: The spot's faint skirt: this share of the power over ``spot_halo_scale`` times its
    #: width (docs/scanner-model.md: chosen there to reproduce issue 18's real retro-reflective
    #: rod's ramps). A surface close behind that is much brighter than the rod merges through
    #: it into every beam's echo: a matte 20 mm rod at 0.1 m before a wall 0.3 m behind (the
    #: wall 16 times the rod's power) read every beam 4-5 mm long, the centre 4.7 mm long
    #: against 0.6 mm std, where the core alone gave a share of 0.03 %.
    spot_halo_fraction: float = 0.015
    spot_halo_scale: float = 2.5
    #: Where the backgrounds just outside the rod's two edges differ (a step behind one edge),
    #: the spot blends or pulls the edge beams unequally and the fit's centre moves sideways,
    #: the same at every dwell of the pose (a step 0.5-1 m / 2 m behind: 2-5 mm against
    #: 0.6-1.6 mm std, docs/lab/extraction-log.md "Backgrounds not square to the bearing"). Each side's
    #: reach into the rod's echo is its depth behind the rod times the pulse's overlap there
    #: (``exp(-depth^2 / 2 sigma_pulse^2)``: nothing from 2 m); the covariance across the bearing
    #: gets this many spot sigmas of std per pulse sigma between the two sides' reaches
    #: (``_with_uneven_background``).
    uneven_background_doubt: float = 1.5
    #: The spot fit weights its spot's power by a diffuse surface's cosine (``_spot_readings_m``);
    #: a glossy or retro-reflective surface weights the middle more. On the physical model a
    #: retro-reflective rod's noise-free readings differ from that prediction by 1-2.5 mm RMS
    #: where a ray's differ by 4-9 mm: this share of the spot's correction along the bearing
    #: joins the covariance.
    spot_model_doubt: float = 0.5
    #: The fit predicts each beam's reading as its spot returns it from the rod (a power-weighted
    #: mean over the part of the spot on the rod: ``_spot_readings_m``), integrated with this many
    #: Gauss-Legendre nodes across the rod's visible half.
    spot_quadrature_nodes: int = 16
    #: ... and when that surface is nearer behind the rod than about the laser pulse's length
    #: (about 1 m: docs/scanner-model.md), the two merge into one echo whose peak lies between
    #: them: a steady blend. A beam's blend is bounded by its share of the background (the
    #: spot's part beside the rod; with intensities, weighted by the background's power
    #: against the beam's) times the depth behind.
    echo_merge_m: float = 0.85
    #: Fractions of the rod's brightest beam's intensity where the middle of its echo's profile
    #: is read for the centre's position across the bearing (``_across_from_echo_middle``); empty:
    #: the fit's own position across is kept.
    echo_middle_levels: tuple[float, ...] = (0.6, 0.7, 0.8, 0.9)
    #: ... and a surface farther behind returns its own lobe, whose flank still pulls the rod's
    #: echo peak towards it through the laser pulse (gaussian, this long: FWHM in range, the
    #: scanner model's 6.7 ns; ``echo_pull``): a polished 10 mm bit at 0.54 m before a wall 1.0
    #: m behind read 24-39 mm long, its centre 28 mm long against 1.8-4.5 mm std, silent. Where
    #: the scan shows the spot and both scans carry intensities, each beam's pull is estimated
    #: from its share of the surface's power (the spot's part beside the rod, the surface's
    #: intensity in the background scan against the beam's own) ...
    pulse_fwhm_m: float = 1.0
    #: Only on a rod narrower than the spot, whose every beam is such a blend: on a wider rod the
    #: estimate is 1.5-2.6 times the model's own pull in its edge beams (the default job's 40 mm
    #: rod about 1 m before the floor), and the centres it called 21-27 mm long lay 1-2 mm long.
    #: (The spot shows for this by one steady beam beside the rod, flipping beams stepped over,
    #: or one cut off its segment, where ``spot_shown_ramp_beams`` asks three: a polished bit
    #: before a far wall shows no ramp, the beams beside it flip between the two, and the steady
    #: ones beyond read the wall pulled towards the bit. An exact ray shows none.)
    tail_pull_shown_beams: int = 1
    #: ... and taken out of its range where that share is at most this: up to a share of 0.35
    #: the estimate is 1.0-1.4 times the scanner model's own pull (the drill job's bit before
    #: the floor, a wall behind a bit); near a half (equal lobes) it is steep, 1.4-1.8 times
    #: (docs/extraction.md, "The pull a pulse length behind") ...
    max_tail_share_taken_out: float = 0.4
    #: ... this part of it (about the estimate's excess; the rest is left in, as above that
    #: share) ...
    tail_pull_taken_out: float = 0.75
    #: ... keeping this part of what that moved the centre in its covariance; ...
    tail_pull_doubt: float = 0.3
    #: ... and a centre that the whole estimated pull (taken out or not) moves by more than this
    #: many std (Mahalanobis) carries a warning.
    warn_tail_pull_std: float = 2.0
    #: A rod whose every beam is more background than rod is refused: none reads the rod itself ...
    max_blend_share: float = 0.5
    #: An edge beam under this share reads the rod cleanly (``_drop_blended_edges``: the other
    #: edge, more background than rod, is then dropped).
    doubtful_blend_share: float = 0.05
    #: A rod whose least blended beam still has this share of background may be a merged echo
    #: that looks like an arc: its covariance takes every beam's whole bound (otherwise what
    #: the residuals show of it) and the centre carries a warning when that is large; only
    #: where the scan shows the spot wider than the rod: at least
    #: ``spot_shown_ramp_beams`` beams were cut off the rod's segment (steady ramps into a
    #: surface close behind, a bright rod's halo). A 4 mm taped rod at 0.1-0.15 m before a wall
    #: 0.3 m behind lights 13-19 deg of beams and reads the wall in every beam at 2-4 % of its
    #: echo (the tape outshines it): every beam 3 mm long, the centre 3-7 mm long against
    #: 0.8-1.5 mm std. Without that sign (the ideal scanner: exact rays, no steady ramps; its
    #: flipping edge beams are trimmed as unstable) the spot model's share is no evidence of a
    #: blend. Steady beams beside the rod between its edge and the surface behind (a far rod's
    #: ramps, split off its segment by their range jumps: ``_steady_beams_beside``) show the
    #: spot too (3 or more: an exact ray grazing the rod reads one such beam a side). Where it
    #: shows, a fit of ``few_beams_push_max_beams`` or fewer also takes its beams' blend bounds
    #: into its covariance (``_with_shared_push``): its edge beams' spots reach the surface
    #: behind and read long, which its one or two spare beams cannot show (a 45 mm rod at 2-3
    #: m before a wall 0.3 m behind, 3-5 beams: 1.6-3.1 mm long against 0.45-0.9 mm std).
    doubtful_blend_share_spot_shown: float = 0.01
    spot_shown_ramp_beams: int = 3
    #: A centre whose blend allowance (std) exceeds this carries a warning.
    warn_blend_std_m: float = 0.005
    #: What the scanner's range-error curve (one value per distance) leaves across one rod's
    #: beams joins the covariance: range walk with intensity (bright echoes read short; with
    #: intensities: this much per e-fold of intensity against the rod's front beam) and the
    #: steep near-range error (this much at 0.1 m, decaying over ``near_bias_decay_m``; a
    #: UTM-30LX on a flat target: +18 to +22 mm at 0.10-0.115 m; docs/scanner-model.md).
    range_walk_m_per_efold: float = 0.0025
    near_bias_m: float = 0.020
    near_bias_decay_m: float = 0.09
    #: ... and the slope of the scanner's range-error curve over the rod's depth: the solver's
    #: curve moves a centre by one value, the curve's at its distance, while the rod's edge
    #: beams lie up to a radius deeper than its front and read the curve there. Issue 18's real
    #: UTM-30LX-EW: +12 mm at 0.15 m, -13 mm at 0.75 m, +8 mm at 2 m, i.e. 16-21 mm per e-fold
    #: of range between them (the physical model's unit: 4-31 mm; a dark 45 mm rod at 0.5 m,
    #: its edges 0.09 e-folds deeper than its front, read them 2.5 mm longer and its centre lay
    #: 1.1 mm long against 0.5 mm std).
    range_error_slope_m_per_efold: float = 0.015
    #: Without a background scan, what lies behind a beam is the farthest reading this many
    #: beams either side (the background beside the rod).
    behind_window_beams: int = 40
    #: A fit of this many beams or fewer gets its sideways position from the two or three
    #: beams at its edges, which a blend with the background moves: it is checked against the
    #: symmetry of the range profile (``_with_symmetry_doubt``). More beams' arc pins the
    #: centre better than that symmetry, which a background differing left and right bends.
    #: (8 until 2026-11-26: a painted 45 mm rod at 2 m, 10 beams under a 42 mm spot, sat 2.7 mm
    #: sideways against 0.85 mm std, its edges lit unevenly by the surface's specular lobe.)
    symmetry_check_max_beams: int = 10
    #: A fit of this many beams or fewer, where the scan shows the spot, takes its beams' blend
    #: bounds into its covariance (``_with_shared_push``).
    few_beams_push_max_beams: int = 8
    search_radius_m: float = 0.15
    max_rms_radius_fraction: float = 0.1
    max_iterations: int = 50
    #: The fit stops once a step moves the centre less than this fraction of its std.
    fit_tolerance_std: float = 0.01
    min_axis_cos_tilt: float = 0.2
    #: Without ``axis_in_scanner`` the rod may still be tilted: segments up to the width of a
    #: rod tilted this much are accepted (and fitted as circles; a second pass with the axis
    #: fits the ellipse).
    unknown_axis_max_tilt_deg: float = 35.0
    #: ... and the centre of such a circle fit is off by up to ``r (1/cos^2 tilt - 1)`` (the
    #: ellipse's flattest arc fitted as a circle): its covariance gets that much per axis
    #: (divided by sqrt 2) for a rod tilted this much, so that it stays honest.
    unknown_axis_typical_tilt_deg: float = 20.0
    #: A twist drill (``fluted``): each of its two flutes opens this much of the section's
    #: circumference, and its web (what is left between them at the bottom) is this fraction of
    #: the diameter. A beam's spot (20 mm or more) is wider than a drill, so a polished bit's
    #: echo comes from where its surface faces the scanner square: the land's front, on the
    #: circle, or, when a flute faces the scanner, the flute's hollow down to the web, up to
    #: ``(1 - web) r`` behind the circle's front and up to ``r sin(opening / 2)`` aside.
    flute_opening_deg: float = 100.0
    flute_web_fraction: float = 0.16
    #: A polished rod (bare metal, steel) returns its glint from where its surface faces the
    #: beam square, the section's front, so each of its beams reads about the front's range
    #: wherever its spot lies on the rod; where few beams cover it (the spot about as wide as
    #: the rod) the spot fit, which weights a diffuse section's cosine, put the centre 1.5-3.5
    #: mm short against 0.8-1.6 mm std (a 45 mm steel rod 3 m away before a wall 2.5 m behind:
    #: 2.40 mm short on average over 60 dwells, 6 of them more than 3 std off). Such a rod is
    #: told by its echo's fall-off across the rod: its beams' intensities over the brightest,
    #: against a diffuse section's under the spot (``_gloss_ratio``), under this ratio
    #: (physical model, seeds 0, 1, 100: matte, dark, painted 0.78-1.27, retro-reflective
    #: 0.67-1.33, bare metal and steel 0.18-1.03, median 0.40-0.46; 0: never) ...
    glint_gloss_ratio: float = 0.75
    #: ... on this many beams or fewer (``_along_from_glint``).
    glint_max_beams: int = 7

    def shape_tolerance_m(self, radius_m: float) -> float:
        """How far a beam may lie off a rod of ``radius_m``'s surface beyond its noise and still
        be the rod's (``shape_tolerance_fraction`` of the radius, at least ``min_shape_tolerance_m``)."""
        return max(self.shape_tolerance_fraction * radius_m, self.min_shape_tolerance_m)
