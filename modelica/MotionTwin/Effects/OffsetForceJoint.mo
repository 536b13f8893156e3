within MotionTwin.Effects;
model OffsetForceJoint "Joint with a constant gravity or offset force: m*der(v) = u - d*v - F0"
  extends MotionTwin.Effects.JointBase;
  parameter Real F0(unit = "N") = 19.62 "Constant opposing force (e.g. m*g of a vertical axis; 2 kg * 9.81 m/s2)";
equation
  F_effect = F0;
  annotation(__motiontwin(export = true));
end OffsetForceJoint;
