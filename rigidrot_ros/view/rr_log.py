"""Log what :mod:`rigidrot_ros.view.compute` computed to a rerun recording (no rclpy here).

Entities (timeline ``time``: nanoseconds since the first run's ``start_ns``, a duration; in
a campaign, scene time):

- ``/body``: the inertial frame N (its axes drawn thin, x red, y green, z blue);
  ``/body/truth`` the body B as a solid box along its principal axes
  (:func:`~rigidrot_ros.view.compute.box_half_sizes`), turned by the exact ``q_NB``
  (``Transform3D``; the same values as float64 in its ``q_NB_xyzw`` and
  ``omega_BN_B`` columns); ``/body/truth/omega`` the body rate, an arrow in B;
  ``/body/estimate/<topic>`` each estimate's box as a wireframe ghost;
- ``/error/<topic>/angle`` and ``/error/<topic>/3sigma``: ``|e|`` and its 3σ, rad;
- ``/nees/<topic>`` and ``/nees/band_95/{lo,hi}``: NEES per sample and its band;
- ``/residual/gyro/<topic>`` (x, y, z, rad/s), ``/residual/star_tracker/<topic>``
  (x, y, z of ``e``, rad), ``/residual/rate/<topic>`` (``|omega_est - omega_true|``);
- ``/campaign/...``: the Monte Carlo NEES, its band, the per-run ANEES;
- ``/runs``: the run descriptions the truth was computed from (JSON, in no view);
- ``/notes``: what is shown, decimated or left out, and why (Markdown).
"""

import json

import numpy as np
import pyarrow as pa
import rerun as rr
import rerun.blueprint as rrb

from rigidrot_ros.view.compute import NEES_BAND_1

__all__ = ['Recorder', 'TRUTH_COLOR', 'ESTIMATE_COLORS', 'entity', 'blueprint',
           'campaign_blueprint', 'TIMELINE', 'log_plan', 'log_campaign']

TIMELINE = 'time'
#: Solid box of the truth, and the ghosts of the estimates, in this order.
TRUTH_COLOR = (46, 204, 64)
ESTIMATE_COLORS = ((255, 133, 27), (0, 116, 217), (177, 13, 201), (255, 65, 54))
#: The body rate arrow.
RATE_COLOR = (20, 20, 20)
_XYZ = ((230, 60, 60), (60, 170, 60), (60, 90, 230))
_BAND = (150, 150, 150)


def entity(label):
    """Return an entity path part for a topic label (``/a/b [f]`` -> ``a_b_f``)."""
    text = ''.join(c if c.isalnum() or c in '_-' else '_' for c in label.strip('/'))
    return '_'.join(p for p in text.split('_') if p) or 'topic'


def _body_view():
    return rrb.Spatial3DView(
        origin='/body', name='body in N: truth solid, estimates wireframe, rate arrow',
        eye_controls=rrb.EyeControls3D(position=[2.5, -2.8, 1.9], look_target=[0, 0, 0],
                                       eye_up=[0, 0, 1]))


def _run_views():
    left = rrb.Vertical(_body_view(), rrb.TextDocumentView(origin='/notes', name='notes'),
                        row_shares=[3, 1])
    right = rrb.Vertical(
        rrb.TimeSeriesView(origin='/error', name='attitude error |e| and its 3σ, rad'),
        rrb.TimeSeriesView(origin='/nees', name='NEES and the 95 % band of one sample'),
        rrb.TimeSeriesView(origin='/residual',
                           contents=['+ /residual/gyro/**', '+ /residual/rate/**'],
                           name='gyro ω_meas − ω_true in B; estimated rates |ω_est − ω_true|; '
                                'rad/s'),
        rrb.TimeSeriesView(origin='/residual/star_tracker',
                           name='star tracker error e in B, rad'),
    )
    return rrb.Horizontal(left, right, column_shares=[2, 3], name='run')


def blueprint():
    """Return the layout of one run (live or a bag): the box left, the plots right."""
    return rrb.Blueprint(_run_views(), rrb.TimePanel(state='collapsed'),
                         rrb.SelectionPanel(state='collapsed'),
                         rrb.BlueprintPanel(state='collapsed'), auto_views=False)


def campaign_blueprint(with_run=None):
    """Return the layout of a campaign, with a tab for the run opened (``with_run``)."""
    camp = rrb.Vertical(
        rrb.TimeSeriesView(origin='/campaign/nees',
                           name='Monte Carlo NEES over the runs and its 95 % band'),
        rrb.Horizontal(
            rrb.BarChartView(origin='/campaign/per_run_anees', name='ANEES of each run'),
            rrb.TextDocumentView(origin='/campaign/notes', name='campaign'),
            column_shares=[3, 2]),
        name='campaign')
    parts = [camp] if with_run is None else [_run_views(), camp]
    if with_run is not None:
        parts[0].name = f'run {with_run}'
    root = rrb.Tabs(*parts, active_tab=0) if len(parts) > 1 else parts[0]
    return rrb.Blueprint(root, rrb.TimePanel(state='collapsed'),
                         rrb.SelectionPanel(state='collapsed'),
                         rrb.BlueprintPanel(state='collapsed'), auto_views=False)


def _rows(a):
    """(N, k) float64 as an arrow column of N fixed-size lists (kept as float64)."""
    a = np.ascontiguousarray(a, dtype=np.float64)
    return pa.FixedSizeListArray.from_arrays(pa.array(a.ravel()), a.shape[1])


def _time(stamps_ns, t0_ns):
    return rr.TimeColumn(TIMELINE, duration=(np.asarray(stamps_ns, dtype=np.int64)
                                             - int(t0_ns)).astype('timedelta64[ns]'))


class Recorder:
    """A rerun recording with the viewer's sinks: a local gRPC server, a .rrd file, both.

    Parameters
    ----------
    blueprint : rerun.blueprint.Blueprint
        The layout the viewer opens on.
    grpc_port : int, optional
        Serve the recording on ``127.0.0.1:grpc_port`` (rerun's gRPC proxy).
    save : str, optional
        Also write it to this ``.rrd`` file.
    """

    def __init__(self, blueprint, grpc_port=None, save=None, t0_ns=0):
        self.rec = rr.RecordingStream('rigidrot_view')
        sinks = []
        if grpc_port:
            sinks.append(rr.GrpcServerSink(bind_ip='127.0.0.1', port=int(grpc_port)))
        if save:
            sinks.append(rr.FileSink(save))
        if not sinks:
            raise ValueError('nothing to log to: give a port to serve or a file to save')
        self.rec.set_sinks(*sinks, default_blueprint=blueprint)
        self.t0_ns = int(t0_ns)
        self.url = f'rerun+http://127.0.0.1:{int(grpc_port)}/proxy' if grpc_port else None
        self._styled = set()

    def serve_web(self, web_port):
        """Serve the web viewer (in the wheel) on ``web_port``, connected to the recording."""
        rr.serve_web_viewer(web_port=int(web_port), open_browser=False, connect_to=self.url)

    def flush(self):
        """Write out what was logged (blocks until the sinks have it)."""
        self.rec.flush()

    def close(self):
        """Flush and disconnect the sinks (finishes the .rrd file)."""
        self.rec.flush()
        self.rec.disconnect()

    # -- static parts -----------------------------------------------------------------------
    def body(self, half_sizes, estimates):
        """Log the boxes: the truth solid, each estimate (labels, in order) a wireframe."""
        log = self.rec.log
        log('/body', rr.Arrows3D(vectors=np.eye(3) * 1.6, colors=_XYZ, radii=0.008,
                                 labels=['x_N', 'y_N', 'z_N']), static=True)
        log('/body/truth', rr.Boxes3D(half_sizes=[half_sizes], colors=[TRUTH_COLOR],
                                      fill_mode='solid'), static=True)
        for k, label in enumerate(estimates):
            self.estimate_box(k, label, half_sizes)

    def estimate_box(self, k, label, half_sizes):
        """Log estimate ``k``'s ghost box (a wireframe, slightly larger than the truth)."""
        color = ESTIMATE_COLORS[k % len(ESTIMATE_COLORS)]
        self.rec.log(f'/body/estimate/{entity(label)}',
                     rr.Boxes3D(half_sizes=[np.asarray(half_sizes) * 1.04], colors=[color],
                                fill_mode='majorwireframe', radii=0.012),
                     static=True)
        self._series(f'/error/{entity(label)}/angle', color, f'{label} |e|')
        self._series(f'/error/{entity(label)}/3sigma', tuple(c // 2 for c in color),
                     f'{label} 3σ')
        self.rec.log(f'/nees/{entity(label)}',
                     rr.SeriesPoints(colors=[color], names=[label], marker_sizes=[1.5]),
                     static=True)

    def _series(self, path, color, name, width=1.5):
        if path not in self._styled:
            self._styled.add(path)
            self.rec.log(path, rr.SeriesLines(colors=[color], names=[name], widths=[width]),
                         static=True)

    def runs(self, runs):
        """Keep the run descriptions (JSON, ``/runs``; in no view: for a reader of the file)."""
        self.rec.log('/runs', rr.TextDocument(json.dumps(list(runs), sort_keys=True),
                                              media_type='text/plain'), static=True)

    def notes(self, lines, path='/notes'):
        """Log the lines as a Markdown list (replaces the earlier ones)."""
        self.rec.log(path, rr.TextDocument('\n'.join(f'- {ln}' for ln in lines),
                                           media_type='text/markdown'), static=True)

    # -- time series --------------------------------------------------------------------------
    def truth(self, stamps, q, omega, arrow_scale):
        """Log the truth's box pose, its float64 values and the rate arrow (in B)."""
        if not len(stamps):
            return
        idx = [_time(stamps, self.t0_ns)]
        q = np.asarray(q, dtype=float)
        omega = np.asarray(omega, dtype=float)
        self.rec.send_columns(
            '/body/truth', indexes=idx,
            columns=[*rr.Transform3D.columns(quaternion=q),
                     *rr.AnyValues.columns(q_NB_xyzw=_rows(q), omega_BN_B=_rows(omega))])
        self.rec.send_columns(
            '/body/truth/omega', indexes=idx,
            columns=rr.Arrows3D.columns(vectors=omega * arrow_scale,
                                        colors=np.tile(RATE_COLOR, (len(q), 1)),
                                        radii=np.full(len(q), 0.025)))

    def estimate(self, label, stamps, q, angle, bound3, nees_values):
        """Log an estimate: its ghost's pose, ``|e|``, its 3σ and its NEES (NaN left out)."""
        if not len(stamps):
            return
        name = entity(label)
        ok = np.all(np.isfinite(q), axis=1)
        if ok.any():
            self.rec.send_columns(f'/body/estimate/{name}', indexes=[_time(stamps[ok],
                                                                           self.t0_ns)],
                                  columns=rr.Transform3D.columns(quaternion=q[ok]))
        self.scalars(f'/error/{name}/angle', stamps, angle)
        self.scalars(f'/error/{name}/3sigma', stamps, bound3)
        self.scalars(f'/nees/{name}', stamps, nees_values)

    def nees_band(self, stamps, band):
        """Log the 95 % band's two lines at ``stamps``."""
        if not len(stamps):
            return
        for which, value in zip(('lo', 'hi'), band):
            self._series(f'/nees/band_95/{which}', _BAND, f'95 % band {which} {value:.3g}', 1.0)
            self.scalars(f'/nees/band_95/{which}', stamps, np.full(len(stamps), value))

    def vectors(self, path, stamps, values, names):
        """Log (N, 3) values as three series x, y, z (NaN rows left out)."""
        values = np.asarray(values, dtype=float)
        ok = np.all(np.isfinite(values), axis=1)
        if not ok.any():
            return
        if path not in self._styled:
            self._styled.add(path)
            self.rec.log(path, rr.SeriesLines(colors=list(_XYZ), names=names, widths=[1.0] * 3),
                         static=True)
        self.rec.send_columns(path, indexes=[_time(np.asarray(stamps)[ok], self.t0_ns)],
                              columns=rr.Scalars.columns(scalars=values[ok]).partition(
                                  [3] * int(ok.sum())))

    def scalars(self, path, stamps, values):
        """Log one series (NaN samples left out)."""
        values = np.asarray(values, dtype=float)
        ok = np.isfinite(values)
        if ok.any():
            self.rec.send_columns(path, indexes=[_time(np.asarray(stamps)[ok], self.t0_ns)],
                                  columns=rr.Scalars.columns(scalars=values[ok]))

    def bars(self, path, values, abscissa, color=(0, 116, 217)):
        """Log a bar chart (static)."""
        self.rec.log(path, rr.BarChart(np.asarray(values, dtype=float), color=color,
                                       abscissa=np.asarray(abscissa, dtype=float)),
                     static=True)


def log_plan(rec, plan, static=True):
    """Draw a :class:`~rigidrot_ros.view.plan.Plan`: its boxes and notes too if ``static``."""
    if static:
        rec.body(plan.half_sizes, [e['label'] for e in plan.estimates])
        rec.notes(plan.notes + plan.problems)
        rec.runs(plan.runs)
    if plan.truth is not None:
        rec.truth(plan.truth['stamps'], plan.truth['q'], plan.truth['omega'],
                  plan.arrow_scale)
    for e in plan.estimates:
        rec.estimate(e['label'], e['stamps'], e['q'], e['angle'], e['bound3'], e['nees'])
    if plan.estimates:
        stamps = np.unique(np.concatenate([e['stamps'][np.isfinite(e['nees'])]
                                           for e in plan.estimates]))
        rec.nees_band(stamps, NEES_BAND_1)
    for g in plan.gyro:
        rec.vectors(f'/residual/gyro/{entity(g["label"])}', g['stamps'], g['residual'],
                    [f'{g["label"]} {a}' for a in 'xyz'])
    for s in plan.star:
        rec.vectors(f'/residual/star_tracker/{entity(s["label"])}', s['stamps'], s['e'],
                    [f'{s["label"]} e_{a}' for a in 'xyz'])
    for k, r in enumerate(plan.rates):
        path = f'/residual/rate/{entity(r["label"])}'
        rec._series(path, ESTIMATE_COLORS[k % len(ESTIMATE_COLORS)],
                    f'{r["label"]} |ω_est − ω_true|', 2.0)
        rec.scalars(path, r['stamps'], r['error'])


def log_campaign(rec, cplan):
    """Draw a campaign (:func:`rigidrot_ros.view.campaign.campaign_plan`): NEES, ANEES."""
    rec.notes(cplan['notes'], path='/campaign/notes')
    if cplan['nees'] is not None:
        c = cplan['nees']
        stamps = c['t_ns'] + rec.t0_ns
        rec._series('/campaign/nees/mc', ESTIMATE_COLORS[1], 'NEES averaged over the runs')
        rec.scalars('/campaign/nees/mc', stamps, c['nees'])
        for which, value in zip(('lo', 'hi'), c['band']):
            rec._series(f'/campaign/nees/band_95_{which}', _BAND,
                        f'95 % band {which} {value:.3g}', 1.0)
            rec.scalars(f'/campaign/nees/band_95_{which}', stamps, np.full(len(stamps), value))
    if cplan['per_run'] is not None:
        p = cplan['per_run']
        rec.bars('/campaign/per_run_anees', p['anees'], p['runs'])
