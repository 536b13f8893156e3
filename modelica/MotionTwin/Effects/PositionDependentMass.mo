within MotionTwin.Effects;
function PositionDependentMass "Configuration-dependent inertia m(x) = m0*(1 + dm*cos(2*pi*x/period)) and its derivative dm/dx"
  input Real x(unit = "m") "Position";
  input Real m0(unit = "kg") "Mean inertia";
  input Real dm(unit = "1") "Relative variation (|dm| < 1)";
  input Real period(unit = "m") "Spatial period of the variation";
  output Real mass(unit = "kg") "Inertia m(x)";
  output Real dmass(unit = "kg/m") "Derivative dm/dx";
protected
  Real k "Spatial wavenumber 2*pi/period";
algorithm
  k := 6.283185307179586 / period;
  mass := m0 * (1 + dm * cos(k * x));
  dmass := -m0 * dm * k * sin(k * x);
end PositionDependentMass;
