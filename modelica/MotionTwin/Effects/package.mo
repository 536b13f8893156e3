within MotionTwin;
package Effects "Physical effects added to a joint model. Sign convention for every joint below: m*der(v) = u - d*v - F_effect, i.e. a positive effect force opposes positive motion; friction laws return a force that opposes the velocity and are smoothed with tanh(v/v_eps) (76 % of the level at v = v_eps)"
end Effects;
