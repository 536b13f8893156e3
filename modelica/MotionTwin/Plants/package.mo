within MotionTwin;
package Plants "Mechanical plants: linear-motor joints, 4-DOF parallel manipulator (Cheung and Hung), serial robot joint (Bona and Curatella), 6-DOF hexapod (Abdellatif and Heimann)"
end Plants;
