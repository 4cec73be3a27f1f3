"""Mode shapes in the model update: the modal constants, compared where no channel gain or per-mode factor enters.

The thesis' update (ch. 5.2-5.3) matches resonance and anti-resonance
frequencies.  Where the features fix fewer combinations of the moduli than
there are moduli (demo20's four per-element moduli from multisine data: three
of four, issue 19), the mode shapes at the bearings add what the frequencies
lack.  They are in the fitted channels' modal constants
(`ambid.channel_fit.ChannelModel.modal_constants`): for a lightly damped mode
``m`` of one plane,

    C_m(o, i) = s_o phi_m(o) phi_m(i) a_i / mu_m,

the mode shape at sensor ``o`` and actuator ``i`` times the sensor's gain
``s_o``, the actuator's ``a_i`` and a factor ``mu_m`` of the mode (modal mass,
and any dynamics the model lacks at that frequency: a delay, a filter).  The
gains are what calibration gets wrong by a percent or more and the diagnosis
may still be looking for; so the update compares ``log |C|`` only after
removing, per plane, one offset per sensor, one per actuator and one per mode
(weighted least squares): what is left are contrasts such as

    log |C_m(D, i) / C_m(N, i)| - log |C_1(D, i) / C_1(N, i)|,

how the ratio of the shape at the two sensors changes from mode to mode.  Those
depend on the rotor alone.  One mode gives none (a rank-one residue matrix is
all offsets); each further mode of a 2 x 2 plane gives two.
"""

import numpy as np
import pandas as pd

__all__ = ["ModeShapeContrasts"]


class ModeShapeContrasts:
    """Whitened residuals of the measured modal constants after the per-plane offsets are fitted out.

    Parameters
    ----------
    measured : pandas.DataFrame
        `ambid.update.measured_features` rows; the pole rows with a finite
        ``modal_constant`` above rounding level (1e-9 of the channel's largest) take part.
    floor : float
        Smallest relative standard uncertainty of a constant (the fit's own,
        ``modal_constant_std``, does not hold the few-tenths-of-a-percent
        errors of the force law's level and of the gains' frequency
        dependence).

    Attributes
    ----------
    rows : int array
        Positions in ``measured`` of the constants used.
    log_constant, sigma : arrays
        ``log |C|`` (`soft_log`) and its standard uncertainty (relative): the fit's, at least ``floor``.
    softening : array
        Each constant's absolute standard uncertainty, where `soft_log` leaves the log.
    """

    def __init__(self, measured, floor):
        constant = measured["modal_constant"].to_numpy(float) if "modal_constant" in measured else np.full(len(measured), np.nan)
        std = (measured["modal_constant_std"].to_numpy(float) if "modal_constant_std" in measured
               else np.full(len(measured), np.nan))
        use = (measured["root"].to_numpy() == "pole") & np.isfinite(constant)
        # a mode the channel does not see (a constant at rounding level against the channel's others) has no shape
        channel = measured["output"].astype(str).to_numpy() + "/" + measured["input"].astype(str).to_numpy()
        largest = pd.Series(np.where(use, np.abs(constant), 0.0)).groupby(channel).transform("max").to_numpy()
        use &= np.abs(constant) > 1e-9 * largest
        self.rows = np.flatnonzero(use)
        self.outputs = measured["output"].to_numpy()[use]
        self.inputs = measured["input"].to_numpy()[use]
        self.planes = np.array([o[1] for o in self.outputs])
        numbers = measured["number"].to_numpy()[use]
        #: whether some plane has constants of two measured modes or more (else no contrast at all)
        self.several_modes = any(np.unique(numbers[self.planes == plane]).size > 1 for plane in np.unique(self.planes))
        constant = constant[use]
        self.sigma = np.fmax(std[use], floor)
        self.sigma = np.where(np.isfinite(self.sigma), self.sigma, np.inf)
        # the log is softened at each constant's own absolute uncertainty: a model constant passing through zero
        # (a node of the shape crossing a bearing) costs a bounded amount
        self.softening = np.where(np.isfinite(self.sigma), self.sigma, 1.0) * np.abs(constant)
        self.log_constant = self.soft_log(constant)
        self._projection_key, self._projection = None, None

    def soft_log(self, constant):
        """``log |C|`` where ``|C|`` is at least ``softening``; below, the log of ``(C^2 + softening^2) / (2 softening)``
        (value and slope continuous, at least ``log(softening / 2)``)."""
        return np.log(self._soft_abs(np.asarray(constant, dtype=float)))

    def _soft_abs(self, constant):
        return np.where(np.abs(constant) >= self.softening, np.abs(constant),
                        (constant**2 + self.softening**2) / (2 * self.softening))

    def _soft_log_slope(self, constant):
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(np.abs(constant) >= self.softening, 1.0 / constant,
                            constant / self.softening / self._soft_abs(constant))

    def __len__(self):
        return self.rows.size

    def projection(self, modes):
        """``I - Q Q^T`` per plane, Q an orthonormal basis of the whitened offsets (sensor, actuator, mode).

        ``modes``: the model mode (pole index of the plane) each constant is matched to.  Kept for the last
        matching (it changes only when the optimizer moves a mode past another).
        """
        key = np.asarray(modes).tobytes()
        if self._projection_key != key:
            self._projection_key, self._projection = key, self._projection_for(np.asarray(modes))
        return self._projection

    def _projection_for(self, modes):
        n = len(self)
        projection = np.zeros((n, n))
        weight = np.where(np.isfinite(self.sigma), 1.0 / self.sigma, 0.0)
        for plane in np.unique(self.planes):
            index = np.flatnonzero(self.planes == plane)
            columns = [self.outputs[index] == o for o in np.unique(self.outputs[index])]
            columns += [self.inputs[index] == i for i in np.unique(self.inputs[index])]
            columns += [modes[index] == m for m in np.unique(modes[index])]
            offsets = np.column_stack(columns).astype(float) * weight[index, None]
            basis, singular, _ = np.linalg.svd(offsets, full_matrices=False)
            basis = basis[:, singular > 1e-10 * max(singular.max(initial=0.0), 1e-300)]
            projection[np.ix_(index, index)] = np.eye(index.size) - basis @ basis.T
        return projection

    def contrasts(self, modes):
        """How many contrasts the constants give: their count less the independent offsets (the trace of
        `projection`); the degrees of freedom they add to a chi2."""
        if not len(self):
            return 0
        # a constant of infinite uncertainty keeps a 1 on the diagonal and carries nothing
        return int(round(np.trace(self.projection(np.asarray(modes))))) - int(np.sum(~np.isfinite(self.sigma)))

    def residuals(self, model_constant, modes, model_derivatives=None):
        """Whitened contrasts ``P (log|C_model| - log|C_measured|) / sigma`` (`soft_log`) and their derivatives.

        Parameters
        ----------
        model_constant : array (n,)
            The modal constant of the model mode matched to each measured one.
        modes : int array (n,)
            That mode's pole index in its plane.
        model_derivatives : array (n, n_variables), optional
            ``d C_model / d values``.

        Returns
        -------
        residual : array (n,)
            In units of the standard uncertainties; contributes ``residual @ residual`` to a chi2 with ``n`` minus the
            offsets' count degrees of freedom.
        jacobian : array (n, n_variables) or None
        """
        projection = self.projection(np.asarray(modes))
        weight = np.where(np.isfinite(self.sigma), 1.0 / self.sigma, 0.0)
        model_constant = np.asarray(model_constant, dtype=float)
        residual = projection @ (weight * (self.soft_log(model_constant) - self.log_constant))
        if model_derivatives is None:
            return residual, None
        return residual, projection @ ((weight * self._soft_log_slope(model_constant))[:, None] * model_derivatives)
